"""Write step times to ``.npz`` and ``.csv``, streaming and atomically.

Arrays arrive chunk by chunk (their length is unknown until the end), so each
key is spooled to a raw file in a private temporary directory beside the
output; :meth:`NpzStreamWriter.commit` then writes the ``.npz`` under a
temporary name (each member an ``.npy`` header followed by the raw bytes,
copied in blocks) and renames it over the target. Any error or Ctrl-C before
the rename leaves no partial file: :meth:`abort` removes the spool and the
temporary name. Memory stays bounded by the copy block size.

The ``.npz`` layout is that of ../shared/reference/klipper/steps/: per stepper
``<name>`` (float64 s from the start of the first move) and ``<name>_dir``
(int8 ±1), plus ``steppers`` (names in order), ``steps_per_mm`` (float64 per
stepper) and ``kinematics``; with compression ``<name>_runs`` (RUN_DTYPE),
``clock_hz`` and ``max_error_s``.
"""
from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from ..errors import GcodeplanError

COPY_BLOCK = 1 << 22


def _io_error(path: Path | str, err: OSError) -> GcodeplanError:
    reason = err.strerror or str(err)
    return GcodeplanError(f"cannot write {path}: {reason}")


def _check_dir(directory: Path, what: Path) -> None:
    if not directory.is_dir():
        raise GcodeplanError(f"cannot write {what}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise GcodeplanError(f"cannot write {what}: directory {directory} is not writable")


class NpzStreamWriter:
    """A ``.npz`` built from 1-D arrays appended in chunks; written atomically on :meth:`commit`.

    Use as a context manager: commit on a clean exit, abort on an exception.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        _check_dir(self.path.parent if str(self.path.parent) else Path("."), self.path)
        try:
            self._spool = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".spool",
                                                dir=self.path.parent))
        except OSError as err:
            raise _io_error(self.path, err) from None
        self._keys: dict[str, tuple[np.dtype, Path, int]] = {}   # key -> (dtype, spool file, length)
        self._files: dict[str, object] = {}
        self._small: dict[str, np.ndarray] = {}
        self._done = False

    def declare(self, key: str, dtype) -> None:
        """Create ``key`` (possibly empty) with this dtype; its order is the order of declaration."""
        if key in self._keys or key in self._small:
            raise ValueError(f"duplicate key {key!r}")
        f = self._spool / f"{len(self._keys):04d}.raw"
        try:
            self._files[key] = open(f, "wb")
        except OSError as err:
            raise _io_error(self.path, err) from None
        self._keys[key] = (np.dtype(dtype), f, 0)

    def append(self, key: str, values: np.ndarray) -> None:
        dtype, f, n = self._keys[key]
        arr = np.ascontiguousarray(values, dtype=dtype)
        try:
            self._files[key].write(arr.tobytes())   # type: ignore[attr-defined]
        except OSError as err:
            raise _io_error(self.path, err) from None
        self._keys[key] = (dtype, f, n + len(arr))

    def put(self, key: str, value) -> None:
        """A small array (metadata) stored whole."""
        if key in self._keys or key in self._small:
            raise ValueError(f"duplicate key {key!r}")
        self._small[key] = np.asarray(value)

    def commit(self) -> None:
        if self._done:
            return
        tmp = None
        try:
            for fh in self._files.values():
                fh.close()   # type: ignore[attr-defined]
            fd, tmp_name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
            os.close(fd)
            tmp = Path(tmp_name)
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
                for key, (dtype, f, n) in self._keys.items():
                    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": (n,)}
                    with zf.open(key + ".npy", "w", force_zip64=True) as out, open(f, "rb") as src:
                        np.lib.format.write_array_header_1_0(out, header)
                        shutil.copyfileobj(src, out, COPY_BLOCK)
                for key, arr in self._small.items():
                    with zf.open(key + ".npy", "w", force_zip64=True) as out:
                        np.lib.format.write_array(out, arr, allow_pickle=False)
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, self.path)
            tmp = None
        except OSError as err:
            raise _io_error(self.path, err) from None
        finally:
            if tmp is not None:
                tmp.unlink(missing_ok=True)
            self._cleanup()
            self._done = True

    def abort(self) -> None:
        if self._done:
            return
        for fh in self._files.values():
            try:
                fh.close()   # type: ignore[attr-defined]
            except OSError:
                pass
        self._cleanup()
        self._done = True

    def _cleanup(self) -> None:
        shutil.rmtree(self._spool, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.abort()
        return False


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class CsvStepWriter:
    """``DIR/<stepper>.csv`` with header ``time_s,dir``, one row per step; atomic per file."""

    def __init__(self, directory: str | os.PathLike, names: list[str]):
        self.dir = Path(directory)
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise _io_error(self.dir, err) from None
        _check_dir(self.dir, self.dir)
        self.names = list(names)
        self._tmp: list[Path] = []
        self._fh = []
        try:
            for name in self.names:
                fd, tmp = tempfile.mkstemp(prefix=f".{name}.csv.", suffix=".tmp", dir=self.dir)
                fh = os.fdopen(fd, "w", newline="\n")
                self._tmp.append(Path(tmp))
                self._fh.append(fh)
                fh.write("time_s,dir\n")
        except OSError as err:
            self.abort()
            raise _io_error(self.dir, err) from None
        self._done = False

    def append(self, index: int, times: np.ndarray, dirs: np.ndarray) -> None:
        if len(times) == 0:
            return
        # 10 decimals: 0.1 ns, below the 20 ns clock tick any consumer will use
        body = "\n".join(f"{t:.10f},{d:d}" for t, d in zip(times.tolist(), dirs.tolist()))
        try:
            self._fh[index].write(body + "\n")
        except OSError as err:
            raise _io_error(self.dir / f"{self.names[index]}.csv", err) from None

    def commit(self) -> None:
        if self._done:
            return
        try:
            for fh in self._fh:
                fh.close()
            mode = 0o666 & ~_umask()
            for name, tmp in zip(self.names, self._tmp):
                os.chmod(tmp, mode)
                os.replace(tmp, self.dir / f"{name}.csv")
        except OSError as err:
            self.abort()
            raise _io_error(self.dir, err) from None
        self._done = True

    def abort(self) -> None:
        for fh in self._fh:
            try:
                fh.close()
            except OSError:
                pass
        for tmp in self._tmp:
            tmp.unlink(missing_ok=True)
        self._done = True


def load_steps(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of a steps ``.npz`` (ours or Klipper's reference), loaded into memory."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}
