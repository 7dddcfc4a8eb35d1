"""Writing output files whole or not at all.

Every file gcodeplan writes goes through :func:`atomic_output`: the bytes go to a temporary file in
the same directory (named ``.<name>.gcodeplan-<random>.tmp``, so a stale one left by kill -9 is never
taken for output), then replace the target in one ``os.replace``. On any error or interruption the
temporary file is removed and the target is untouched; the permissions of a replaced file are kept.
"""
from __future__ import annotations

import contextlib
import os
import stat
import tempfile

from ..errors import GcodeplanError

TMP_SUFFIX = ".tmp"
TMP_TAG = ".gcodeplan-"


def _check_parent(path: str) -> str:
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise GcodeplanError(f"cannot write {path}: no such directory {parent}")
    if os.path.isdir(path):
        raise GcodeplanError(f"cannot write {path}: it is a directory")
    return parent


@contextlib.contextmanager
def atomic_output(path: str, mode: str = "w", encoding: str | None = "utf-8", newline: str | None = None):
    """``with atomic_output(path, 'wb') as fh: ...``: ``path`` appears complete when the block ends
    without error, and is untouched otherwise."""
    path = str(path)
    parent = _check_parent(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + TMP_TAG, suffix=TMP_SUFFIX, dir=parent)
    except OSError as err:
        raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None
    try:
        kw = {} if "b" in mode else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kw) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        try:
            old = os.stat(path)
            os.chmod(tmp, stat.S_IMODE(old.st_mode))
        except FileNotFoundError:
            os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(err, OSError):
            raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8, newlines as given)."""
    with atomic_output(path, "w", newline="") as fh:
        fh.write(text)


def atomic_write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path, "wb") as fh:
        fh.write(data)
