"""Writing output files whole or not at all, and never leaving a temporary file behind.

Every file gcodeplan writes goes through :func:`atomic_output` (the step writers of
``stepper/export.py`` use the same names and registry): the bytes go to a temporary file in the
same directory, then replace the target in one ``os.replace``. On any error or interruption
(Ctrl-C, SIGTERM, SIGHUP: gcodeplan/signals.py) the temporary file is removed and the target is
untouched; the permissions of a replaced file are kept.

Temporary names are ``.<name>.gcodeplan-<pid>-<random>.tmp`` (``.spool`` for a directory): hidden, never
the target's name, so a stale one left by kill -9 is never taken for output, and the next write to
the same target removes those whose process is gone. Each temporary path is registered while it
exists; :func:`discard_temporaries` (run by ``cli.main`` on the way out) removes any still registered,
so not even an interruption between two statements leaves one.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile

from ..errors import GcodeplanError

TMP_SUFFIX = ".tmp"
SPOOL_SUFFIX = ".spool"
TMP_TAG = ".gcodeplan-"

_live: set[str] = set()       # temporary files and directories of this process that still exist


def temp_prefix(path: str | os.PathLike) -> str:
    """``.<name>.gcodeplan-<pid>-``: the start of every temporary name for the target ``path``."""
    return "." + os.path.basename(str(path)) + TMP_TAG + f"{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:             # e.g. EPERM: it exists, owned by someone else
        return True
    return True


def remove_stale(path: str | os.PathLike) -> int:
    """Remove the temporary files/directories a killed gcodeplan (kill -9, power cut) left for the
    target ``path``: those named after it whose process no longer runs. Returns how many went."""
    parent = os.path.dirname(os.path.abspath(str(path)))
    head = "." + os.path.basename(str(path)) + TMP_TAG
    removed = 0
    try:
        names = os.listdir(parent)
    except OSError:
        return 0
    for name in names:
        if not name.startswith(head) or not name.endswith((TMP_SUFFIX, SPOOL_SUFFIX)):
            continue
        pid_text = name[len(head):].split("-", 1)[0]
        if not pid_text.isdigit() or _pid_alive(int(pid_text)):
            continue
        full = os.path.join(parent, name)
        with contextlib.suppress(OSError):
            if os.path.isdir(full) and not os.path.islink(full):
                shutil.rmtree(full)
            else:
                os.unlink(full)
            removed += 1
    return removed


def register(path: str | os.PathLike) -> None:
    """Note a temporary path of this process (removed by :func:`discard_temporaries` if still there)."""
    _live.add(os.path.abspath(str(path)))


def unregister(path: str | os.PathLike) -> None:
    """The temporary path was renamed to its target or removed."""
    _live.discard(os.path.abspath(str(path)))


def discard_temporaries() -> None:
    """Remove every registered temporary path that still exists (the last safety net on exit)."""
    for p in list(_live):
        with contextlib.suppress(OSError):
            if os.path.isdir(p) and not os.path.islink(p):
                shutil.rmtree(p, ignore_errors=True)
            else:
                os.unlink(p)
        _live.discard(p)


def make_temp_file(path: str | os.PathLike, suffix: str = TMP_SUFFIX) -> tuple[int, str]:
    """(fd, name) of a new registered temporary file beside ``path``; signals are held back until it is
    registered (gcodeplan/signals.py), so an interruption cannot leave it unknown."""
    from ..signals import held

    parent = os.path.dirname(os.path.abspath(str(path)))
    with held():
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=suffix, dir=parent)
        register(tmp)
    return fd, tmp


def make_temp_dir(path: str | os.PathLike) -> str:
    """A new registered temporary directory beside ``path`` (see :func:`make_temp_file`)."""
    from ..signals import held

    parent = os.path.dirname(os.path.abspath(str(path)))
    with held():
        tmp = tempfile.mkdtemp(prefix=temp_prefix(path), suffix=SPOOL_SUFFIX, dir=parent)
        register(tmp)
    return tmp


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
    _check_parent(path)
    remove_stale(path)
    tmp = None
    try:
        try:
            fd, tmp = make_temp_file(path)
        except OSError as err:
            raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None
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
        unregister(tmp)
        tmp = None
    except BaseException as err:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            unregister(tmp)
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
