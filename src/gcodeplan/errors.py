"""Errors a user can act on. The CLI prints ``str(err)`` on one line and exits 2."""
from __future__ import annotations

from contextlib import contextmanager


class GcodeplanError(Exception):
    """Bad input or usage. ``file``/``line`` point at the offending place when known."""

    def __init__(self, message: str, file: str | None = None, line: int | None = None):
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line

    def __str__(self) -> str:
        where = ""
        if self.file is not None:
            where = f"{self.file}:{self.line}: " if self.line is not None else f"{self.file}: "
        elif self.line is not None:
            where = f"line {self.line}: "
        return where + self.message


class ConfigError(GcodeplanError):
    """A machine description (TOML or Klipper cfg) is wrong: names the key."""


class GcodeError(GcodeplanError):
    """A G-code file cannot be read or has a bad line: names file:line."""


@contextmanager
def located(path: str):
    """Give errors raised by stages that only know line numbers (the planner) the file's name."""
    try:
        yield
    except GcodeplanError as err:
        if err.file is None:
            err.file = str(path)
        raise
