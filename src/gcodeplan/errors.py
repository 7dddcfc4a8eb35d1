"""Errors a user can act on. The CLI prints ``str(err)`` on one line and exits 2.

A message quotes the input only in part: :func:`quote` cuts a quoted piece of text to
:data:`QUOTE_CHARS` characters and an ellipsis, and every message is clipped (:func:`clip_message`) so
that a number of 10^8 digits or a word of a million letters in a file cannot make the error itself
megabytes long.
"""
from __future__ import annotations

import re
from contextlib import contextmanager

QUOTE_CHARS = 40           # characters of input text an error quotes, then '…'
WORD_CHARS = 256           # a longer word in a message (no path is this long in practice) is cut to QUOTE_CHARS
MESSAGE_CHARS = 1000       # a message is never longer than this (plus '…')
_LONG_NUMBER = re.compile(r"\d{%d,}" % (QUOTE_CHARS + 1))
_LONG_WORD = re.compile(r"\S{%d,}" % (WORD_CHARS + 1))


def quote(text, limit: int = QUOTE_CHARS) -> str:
    """``text`` (str) as an error quotes it: at most ``limit`` characters, then '…' when cut."""
    text = str(text)
    return text if len(text) <= limit else text[:limit] + "…"


def clip_message(message: str) -> str:
    """``message`` with every run of more than QUOTE_CHARS digits and every word longer than WORD_CHARS cut to
    QUOTE_CHARS characters and '…', and the whole at most MESSAGE_CHARS characters (then '…')."""
    if len(message) <= QUOTE_CHARS:
        return message
    message = _LONG_NUMBER.sub(lambda m: m.group()[:QUOTE_CHARS] + "…", message)
    message = _LONG_WORD.sub(lambda m: m.group()[:QUOTE_CHARS] + "…", message)
    if len(message) > MESSAGE_CHARS:
        message = message[:MESSAGE_CHARS] + "…"
    return message


class GcodeplanError(Exception):
    """Bad input or usage. ``file``/``line`` point at the offending place when known."""

    def __init__(self, message: str, file: str | None = None, line: int | None = None):
        message = clip_message(str(message))
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
