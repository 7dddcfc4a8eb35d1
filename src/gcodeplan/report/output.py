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

What an output path names decides how it is written (:func:`resolve_output`), as a shell's ``>`` would:

* ``-`` is standard output, written as a stream (so is a path naming the very file standard output is,
  e.g. ``/dev/stdout`` while it is redirected to a file);
* a character device, FIFO or socket (``/dev/null``, ``/dev/stdout`` on a pipe, a named pipe) is opened and
  written as a stream: never replaced, never fsync'ed (an error midway leaves what a stream already took);
* a symbolic link is followed: its final target is replaced atomically (with the target's permissions) and
  the link stays a link; a dangling link creates its target, as ``>`` does;
* anything else is a regular file, replaced atomically as described above.

Output no terminal can show (a PNG, an ``.npz``) is refused with a one-line error when the stream is a
terminal (``tty_ok=False``).
"""
from __future__ import annotations

import contextlib
import io
import os
import shutil
import stat
import sys
import tempfile
from dataclasses import dataclass

from ..errors import GcodeplanError
from ..signals import at_restore, held

TMP_SUFFIX = ".tmp"
SPOOL_SUFFIX = ".spool"
TMP_TAG = ".gcodeplan-"

STDOUT = "-"                  # the output name meaning standard output

_live: set[str] = set()       # temporary files and directories of this process that still exist
_made_dirs: list[str] = []    # directories this process created for an output: removed if still empty on exit


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
    """Remove every registered temporary path that still exists, then every directory made for an
    output that is still registered and empty (the last safety net on exit)."""
    for p in list(_live):
        with contextlib.suppress(OSError):
            if os.path.isdir(p) and not os.path.islink(p):
                shutil.rmtree(p, ignore_errors=True)
            else:
                os.unlink(p)
        _live.discard(p)
    remove_made_dirs(list(_made_dirs))


at_restore(discard_temporaries)      # the signal handlers' restore sweeps what is still registered


def make_dirs(directory: str | os.PathLike) -> list[str]:
    """Create ``directory`` and its missing parents (like ``mkdir -p``); returns those created, outermost
    first. They are registered: unless :func:`keep_made_dirs` is called, :func:`remove_made_dirs` or the
    sweep on exit removes those left empty, so an interrupted or failed output leaves no empty directory."""
    missing = []
    d = os.path.abspath(str(directory))
    while not os.path.lexists(d):
        missing.append(d)
        parent = os.path.dirname(d)
        if parent == d:
            break
        d = parent
    made = []
    try:
        for d in reversed(missing):
            with held():
                os.mkdir(d)
                _made_dirs.append(d)
            made.append(d)
    except FileExistsError:     # made meanwhile by someone else: theirs
        pass
    except BaseException:
        remove_made_dirs(made)
        raise
    return made


def keep_made_dirs(made: list[str]) -> None:
    """The output in these directories is complete: they are no longer removed on exit."""
    for d in made:
        with contextlib.suppress(ValueError):
            _made_dirs.remove(d)


def remove_made_dirs(made: list[str]) -> None:
    """Remove the directories of ``made`` (from :func:`make_dirs`) that are empty, innermost first."""
    for d in reversed(made):
        with contextlib.suppress(OSError):
            os.rmdir(d)     # only if empty: never what someone else put there
        with contextlib.suppress(ValueError):
            _made_dirs.remove(d)


def make_temp_file(path: str | os.PathLike, suffix: str = TMP_SUFFIX) -> tuple[int, str]:
    """(fd, name) of a new registered temporary file beside ``path``; signals are held back until it is
    registered (gcodeplan/signals.py), so an interruption cannot leave it unknown."""
    parent = os.path.dirname(os.path.abspath(str(path)))
    with held():
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=suffix, dir=parent)
        register(tmp)
    return fd, tmp


def make_temp_dir(path: str | os.PathLike) -> str:
    """A new registered temporary directory beside ``path`` (see :func:`make_temp_file`)."""
    parent = os.path.dirname(os.path.abspath(str(path)))
    with held():
        tmp = tempfile.mkdtemp(prefix=temp_prefix(path), suffix=SPOOL_SUFFIX, dir=parent)
        register(tmp)
    return tmp


@dataclass(frozen=True)
class OutputTarget:
    """What an output path names (:func:`resolve_output`).

    ``kind``: ``"stdout"`` (standard output), ``"stream"`` (a device, FIFO or socket: opened and written
    in place) or ``"file"`` (a regular file or a new name: replaced atomically). ``path``: as given;
    ``real``: the file to replace (``"file"``: symbolic links followed) or open (``"stream"``);
    ``name``: how messages call it."""

    kind: str
    path: str
    real: str
    name: str

    @property
    def is_stream(self) -> bool:
        return self.kind != "file"

    @property
    def temp_near(self) -> str:
        """The path temporary files for this output are named after and placed beside: the real target
        for a file, a name in the temporary directory for a stream (never a file in /dev)."""
        if self.kind == "file":
            return self.real
        return os.path.join(tempfile.gettempdir(), "gcodeplan-output")


def _same_file(a: os.stat_result, fd: int) -> bool:
    try:
        b = os.fstat(fd)
    except (OSError, ValueError):
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _stdout_fd() -> int | None:
    try:
        return sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return None


def resolve_output(path: str | os.PathLike) -> OutputTarget:
    """Decide how ``path`` is written (see the module docstring); a one-line GcodeplanError when it cannot
    be (a directory, no such directory, a symbolic-link loop)."""
    path = str(path)
    if path == STDOUT:
        return OutputTarget("stdout", path, path, "standard output")
    if path == "":
        raise GcodeplanError("cannot write an output with an empty name")
    try:
        st = os.stat(path)          # follows symbolic links
    except FileNotFoundError:
        st = None
    except OSError as err:
        raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise GcodeplanError(f"cannot write {path}: it is a directory")
        fd = _stdout_fd()
        if fd is not None and _same_file(st, fd):
            return OutputTarget("stdout", path, path, path)
        if not stat.S_ISREG(st.st_mode):
            return OutputTarget("stream", path, path, path)
    real = os.path.realpath(path) if os.path.islink(path) else path
    parent = os.path.dirname(os.path.abspath(real))
    if not os.path.isdir(parent):
        where = "" if real == path else f" (the link's target {real})"
        raise GcodeplanError(f"cannot write {path}{where}: no such directory {parent}")
    if os.path.isdir(real):
        raise GcodeplanError(f"cannot write {path}: it is a directory")
    return OutputTarget("file", path, real, path)


def _refuse_terminal(fh, target: OutputTarget, what: str) -> None:
    with contextlib.suppress(AttributeError, OSError, ValueError):
        if fh.isatty():
            raise GcodeplanError(f"will not write {what} to a terminal ({target.name}): "
                                 "redirect standard output or name a file with -o")


@contextlib.contextmanager
def _stream_output(target: OutputTarget, mode: str, encoding, newline, tty_ok: bool, what: str):
    binary = "b" in mode
    own = None
    if target.kind == "stdout":
        with contextlib.suppress(AttributeError, OSError, ValueError):
            sys.stdout.flush()      # what the command printed before goes first
        raw = getattr(sys.stdout, "buffer", None)
        if raw is None:             # a text-only stand-in (tests capturing output)
            if binary:
                raise GcodeplanError(f"cannot write {what} to {target.name}: it takes text only")
            raw_text = sys.stdout
        else:
            raw_text = None
    else:
        try:
            fd = os.open(target.real, os.O_WRONLY | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
        except OSError as err:
            raise GcodeplanError(f"cannot write {target.name}: {err.strerror or err}") from None
        own = raw = os.fdopen(fd, "wb")
        raw_text = None
    fh = None
    try:
        if not tty_ok:
            _refuse_terminal(raw if raw_text is None else raw_text, target, what)
        if raw_text is not None:
            fh = raw_text
        elif binary:
            fh = raw
        else:
            fh = io.TextIOWrapper(raw, encoding=encoding or "utf-8", newline=newline, write_through=False)
        yield fh
        fh.flush()
        if raw is not None:
            raw.flush()
    except BrokenPipeError:
        if target.kind == "stdout":
            _silence_stdout()
            raise                    # the reader left (`| head`): cli.main ends quietly
        raise GcodeplanError(f"cannot write {target.name}: the reading end was closed") from None
    except OSError as err:
        if target.kind == "stdout":
            _silence_stdout()        # what could not be written is dropped: the exit's flush must not fail
        raise GcodeplanError(f"cannot write {target.name}: {err.strerror or err}") from None
    finally:
        if isinstance(fh, io.TextIOWrapper) and fh is not raw_text:
            with contextlib.suppress(OSError, ValueError):
                fh.detach()          # leave the byte stream open (standard output stays usable)
        if own is not None:
            with contextlib.suppress(OSError):
                own.close()


@contextlib.contextmanager
def atomic_output(path: str, mode: str = "w", encoding: str | None = "utf-8", newline: str | None = None,
                  *, tty_ok: bool = True, what: str = "this output"):
    """``with atomic_output(path, 'wb') as fh: ...``: ``path`` appears complete when the block ends
    without error, and is untouched otherwise. ``-``, devices, FIFOs and sockets are written as streams and
    symbolic links are followed (module docstring); ``tty_ok=False`` refuses a terminal, naming ``what``."""
    target = resolve_output(path)
    if target.is_stream:
        with _stream_output(target, mode, encoding, newline, tty_ok, what) as fh:
            yield fh
        return
    real = target.real
    remove_stale(real)
    tmp = None
    try:
        try:
            fd, tmp = make_temp_file(real)
        except OSError as err:
            raise GcodeplanError(f"cannot write {path}: {err.strerror or err}") from None
        kw = {} if "b" in mode else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kw) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        _keep_mode(tmp, real)
        os.replace(tmp, real)
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


def _keep_mode(tmp: str, real: str) -> None:
    """The replaced file's permissions, or the umask's for a new file."""
    try:
        old = os.stat(real)
        os.chmod(tmp, stat.S_IMODE(old.st_mode))
    except FileNotFoundError:
        os.chmod(tmp, 0o666 & ~_umask())


def _silence_stdout() -> None:
    """Point standard output's descriptor at /dev/null (bytes left in Python's buffer then go nowhere)."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        fd = sys.stdout.fileno()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)


def install_temp(tmp: str | os.PathLike, target: OutputTarget) -> None:
    """Put the finished temporary file ``tmp`` (made with :func:`make_temp_file` near ``target.temp_near``)
    in place: renamed over a file target (its permissions kept), or copied into a stream and removed. For
    writers that must build their output whole before it goes out (``stepper/export.py``'s ``.npz``)."""
    tmp = str(tmp)
    if not target.is_stream:
        _keep_mode(tmp, target.real)
        os.replace(tmp, target.real)
        unregister(tmp)
        return
    try:
        with open(tmp, "rb") as src, _stream_output(target, "wb", None, None, True, "") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        unregister(tmp)


def refuse_terminal(path: str | os.PathLike, what: str) -> OutputTarget:
    """:func:`resolve_output`, refusing (one-line GcodeplanError) an output that is a terminal: for
    output no terminal can show (``what``: e.g. "a PNG picture"), checked before the work starts."""
    target = resolve_output(path)
    tty = False
    if target.kind == "stdout":
        with contextlib.suppress(AttributeError, OSError, ValueError):
            tty = sys.stdout.isatty()
    elif target.kind == "stream" and stat.S_ISCHR(os.stat(target.real).st_mode):
        with contextlib.suppress(OSError):
            fd = os.open(target.real, os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
            try:
                tty = os.isatty(fd)
            finally:
                os.close(fd)
    if tty:
        raise GcodeplanError(f"will not write {what} to a terminal ({target.name}): "
                             "redirect standard output or name a file with -o")
    return target


def default_output(input_path: str | os.PathLike, suffix: str) -> str:
    """The output a command writes when ``-o`` is not given: named after the input and beside it
    (``a.gcode`` → ``a`` + ``suffix``); for standard input (``-``, ``/dev/stdin``, ``<(…)``: an input
    under /dev or /proc) the name is ``stdin`` + ``suffix`` in the current directory."""
    text = str(input_path)
    if text == "-" or os.path.abspath(text).startswith(("/dev/", "/proc/")):
        return "stdin" + suffix
    return os.path.splitext(text)[0] + suffix


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8, newlines as given; ``-`` and streams as streams)."""
    with atomic_output(path, "w", newline="") as fh:
        fh.write(text)


def atomic_write_bytes(path: str, data: bytes, *, tty_ok: bool = True, what: str = "this output") -> None:
    """Write ``data`` to ``path`` atomically (``-`` and streams as streams; see :func:`atomic_output`)."""
    with atomic_output(path, "wb", tty_ok=tty_ok, what=what) as fh:
        fh.write(data)
