"""Write step times to ``.npz`` and ``.csv``, streaming and atomically; read them back.

Arrays arrive chunk by chunk (their length is unknown until the end), so each
key is spooled to a raw file in a private temporary directory beside the
output; :meth:`NpzStreamWriter.commit` then writes the ``.npz`` under a
temporary name (each member an ``.npy`` header followed by the raw bytes,
copied in blocks) and renames it over the target. Any error, Ctrl-C, SIGTERM or
SIGHUP before the rename leaves no partial file: :meth:`abort` removes the spool
and the temporary name (names and the last-resort registry: report/output.py).
Memory stays bounded by the copy block size.

Two forms of the same steps (:func:`load_steps` reads both):

* **plain** (``gcodeplan steps -o s.npz``): the layout of Klipper's reference step files: per stepper
  ``<name>`` (float64 s from the start of the first move) and ``<name>_dir`` (int8 ±1), plus
  ``steppers`` (names in order), ``steps_per_mm`` (float64 per stepper) and ``kinematics``; with
  ``--compress`` also ``<name>_runs`` (RUN_DTYPE), ``clock_hz`` and ``max_error_s``. 9 bytes a step;
  ``np.load`` reads it with no gcodeplan installed, and it compares with Klipper's files directly.
* **compact** (``--format compact``): the same float64 times bit for bit, many times smaller, for
  keeping or sending the steps of big files. Per stepper ``<name>_times_z``: the times' IEEE-754
  bit patterns as int64, differenced (successive steps differ in few low bits: a run of equal
  intervals has equal differences), the bytes of the differences regrouped plane by plane (all
  lowest bytes, then the next ones) and deflated with zlib, block after block;
  ``<name>_dir_z``: the direction bits (1 = +1) packed 8 to a byte per block, deflated;
  ``<name>_blocks``: the number of steps in each block, ``<name>_widths``: the low bytes kept of each
  block's differences (zigzag-coded, so that small negative ones are small too; the higher bytes
  are zero and not stored); ``format`` names the form. Undoing each
  step (inflate, regroup, cumulative sum, view as float64) gives back the very same times.
"""
from __future__ import annotations

import os
import shutil
import zipfile
import zlib
from pathlib import Path

from .._jit import njit
import numpy as np

from ..errors import GcodeplanError
from ..report import output as _out

COPY_BLOCK = 1 << 22
COMPACT_FORMAT = "gcodeplan-compact-steps-1"
ZLIB_LEVEL = 6


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
        self._spool: Path | None = None
        self._keys: dict[str, tuple[np.dtype, Path, int]] = {}   # key -> (dtype, spool file, length)
        self._files: dict[str, object] = {}
        self._small: dict[str, np.ndarray] = {}
        self._done = False
        if str(self.path) != "-" and not self.path.is_symlink():
            _check_dir(self.path.parent if str(self.path.parent) else Path("."), self.path)
        self.target = _out.resolve_output(self.path)    # '-', devices, FIFOs: streams; links followed
        near = Path(self.target.temp_near)
        _check_dir(near.parent if str(near.parent) else Path("."), self.path)
        _out.remove_stale(near)
        try:
            self._spool = Path(_out.make_temp_dir(near))
        except OSError as err:
            raise _io_error(self.path, err) from None

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
        """Add ``values`` (converted to the key's dtype) at the end of array ``key``."""
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
        """Write the ``.npz`` beside the target and rename it over the target; remove the spool."""
        if self._done:
            return
        tmp = None
        try:
            for fh in self._files.values():
                fh.close()   # type: ignore[attr-defined]
            fd, tmp_name = _out.make_temp_file(self.target.temp_near)
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
            _out.install_temp(tmp, self.target)     # renamed over the target, or copied into a stream
            tmp = None
        except OSError as err:
            raise _io_error(self.path, err) from None
        finally:
            if tmp is not None:
                tmp.unlink(missing_ok=True)
                _out.unregister(tmp)
            self._cleanup()
            self._done = True

    def abort(self) -> None:
        """Drop everything written so far; the target is untouched."""
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
        if self._spool is not None:
            shutil.rmtree(self._spool, ignore_errors=True)
            _out.unregister(self._spool)

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
        self._done = False
        try:
            for name in self.names:
                target = self.dir / f"{name}.csv"
                _out.remove_stale(target)
                fd, tmp = _out.make_temp_file(target)
                self._tmp.append(Path(tmp))
                fh = os.fdopen(fd, "w", newline="\n")
                self._fh.append(fh)
                fh.write("time_s,dir\n")
        except OSError as err:
            self.abort()
            raise _io_error(self.dir, err) from None
        except BaseException:
            self.abort()
            raise

    def append(self, index: int, times: np.ndarray, dirs: np.ndarray) -> None:
        """Rows for stepper ``index``: times (s, 10 decimals) and directions (±1)."""
        if len(times) == 0:
            return
        # 10 decimals: 0.1 ns, below the 20 ns clock tick any consumer will use
        body = "\n".join(f"{t:.10f},{d:d}" for t, d in zip(times.tolist(), dirs.tolist()))
        try:
            self._fh[index].write(body + "\n")
        except OSError as err:
            raise _io_error(self.dir / f"{self.names[index]}.csv", err) from None

    def commit(self) -> None:
        """Rename every temporary file over its ``<stepper>.csv``."""
        if self._done:
            return
        try:
            for fh in self._fh:
                fh.close()
            mode = 0o666 & ~_umask()
            for name, tmp in zip(self.names, self._tmp):
                os.chmod(tmp, mode)
                os.replace(tmp, self.dir / f"{name}.csv")
                _out.unregister(tmp)
        except OSError as err:
            self.abort()
            raise _io_error(self.dir, err) from None
        self._done = True

    def abort(self) -> None:
        """Remove the temporary files; targets untouched (those already renamed stay)."""
        for fh in self._fh:
            try:
                fh.close()
            except OSError:
                pass
        for tmp in self._tmp:
            tmp.unlink(missing_ok=True)
            _out.unregister(tmp)
        self._done = True


# ---------------------------------------------------------------------------- compact form

@njit(cache=True)
def pack_time_planes(bits, last):
    """Differences of the int64 bit patterns ``bits`` (the first from ``last``), zigzag-coded (0, -1, 1,
    -2 … → 0, 1, 2, 3 …: small magnitudes stay small) → (k, planes): the k low byte planes that hold
    them (all lowest bytes, then the next …; the higher bytes are zero and not stored)."""
    n = bits.shape[0]
    top = np.uint64(0)
    prev = last
    for i in range(n):
        d = bits[i] - prev          # int64 wraps: the cumulative sum undoes it exactly
        prev = bits[i]
        u = np.uint64((d << 1) ^ (d >> 63))
        if u > top:
            top = u
    k = 0
    while k < 8 and (top >> np.uint64(8 * k)) != 0:
        k += 1
    planes = np.empty(k * n, np.uint8)
    prev = last
    for i in range(n):
        d = bits[i] - prev
        prev = bits[i]
        u = np.uint64((d << 1) ^ (d >> 63))
        for b in range(k):
            planes[b * n + i] = np.uint8((u >> np.uint64(8 * b)) & np.uint64(0xFF))
    return k, planes


@njit(cache=True)
def unpack_time_planes(planes, k, n, last, out):
    """Inverse of :func:`pack_time_planes`: bit patterns into ``out`` (int64, n); returns the last one."""
    prev = last
    for i in range(n):
        u = np.uint64(0)
        for b in range(k):
            u |= np.uint64(planes[b * n + i]) << np.uint64(8 * b)
        d = np.int64(u >> np.uint64(1)) ^ -np.int64(u & np.uint64(1))
        prev = prev + d
        out[i] = prev
    return prev


class CompactEncoder:
    """Lossless compression of one stepper's (times, dirs) stream, chunk by chunk (module docstring).

    :meth:`feed` returns the compressed bytes of times and dirs made so far, :meth:`finish` the rest;
    :attr:`blocks` lists the steps of each chunk fed and :attr:`widths` the bytes kept per difference.
    """

    def __init__(self, level: int = ZLIB_LEVEL):
        self._times = zlib.compressobj(level)
        self._dirs = zlib.compressobj(level)
        self._last = np.int64(0)      # bit pattern of the last time fed (the first delta is from 0)
        self.blocks: list[int] = []
        self.widths: list[int] = []

    def feed(self, times: np.ndarray, dirs: np.ndarray) -> tuple[bytes, bytes]:
        """Compress one chunk: times (float64 s) and dirs (int8, each ±1)."""
        n = len(times)
        if n == 0:
            return b"", b""
        times = np.ascontiguousarray(times, dtype=np.float64)
        dirs = np.asarray(dirs)
        if len(dirs) != n or not np.all((dirs == 1) | (dirs == -1)):
            raise ValueError("step directions must be +1 or -1, one per step time")
        bits = times.view(np.int64)
        k, planes = pack_time_planes(bits, self._last)
        self._last = bits[-1]
        self.blocks.append(n)
        self.widths.append(int(k))
        return self._times.compress(planes), self._dirs.compress(np.packbits(dirs > 0).tobytes())

    def finish(self) -> tuple[bytes, bytes]:
        """The compressed tails of both streams."""
        return self._times.flush(), self._dirs.flush()


def decode_compact(times_z, dirs_z, blocks, widths) -> tuple[np.ndarray, np.ndarray]:
    """(times float64 s, dirs int8 ±1) from one stepper's compact members (inverse of CompactEncoder)."""
    blocks = np.asarray(blocks, dtype=np.int64)
    widths = np.asarray(widths, dtype=np.int64)
    total = int(blocks.sum())
    raw_t = memoryview(zlib.decompress(np.asarray(times_z, dtype=np.uint8).tobytes()))
    raw_d = memoryview(zlib.decompress(np.asarray(dirs_z, dtype=np.uint8).tobytes()))
    if len(blocks) != len(widths) or len(raw_t) != int((blocks * widths).sum()) \
            or len(raw_d) != int(((blocks + 7) // 8).sum()):
        raise GcodeplanError("compact step file: stream lengths do not match the block counts (damaged file?)")
    bits = np.empty(total, np.int64)
    dirs = np.empty(total, np.int8)
    pt = pd = k = 0
    last = np.int64(0)
    for n, w in zip(blocks.tolist(), widths.tolist()):
        last = unpack_time_planes(np.frombuffer(raw_t[pt:pt + w * n], np.uint8), w, n, last, bits[k:k + n])
        nb = (n + 7) // 8
        up = np.unpackbits(np.frombuffer(raw_d[pd:pd + nb], np.uint8))[:n]
        dirs[k:k + n] = up.view(np.int8) * np.int8(2) - np.int8(1)
        pt += w * n
        pd += nb
        k += n
    return bits.view(np.float64), dirs


def load_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of a steps ``.npz`` (plain or compact, ours or Klipper's reference), as stored."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def load_steps(path: str | os.PathLike) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{stepper: (times float64 s, dirs int8 ±1)}`` from a steps file of either form (or one of
    Klipper's reference files), in the file's stepper order. The compact form gives back the very
    same float64 times as the plain one."""
    try:
        z = load_npz(path)
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise GcodeplanError(f"cannot read steps from {path}: {err}") from None
    if "steppers" in z:
        names = [str(n) for n in z["steppers"]]
    else:    # no list: every float array with a _dir partner
        names = [k for k in z if k + "_dir" in z or k + "_times_z" in z]
    compact = "format" in z and str(z["format"]) == COMPACT_FORMAT
    out = {}
    for name in names:
        if compact:
            out[name] = decode_compact(z[name + "_times_z"], z[name + "_dir_z"], z[name + "_blocks"],
                                       z[name + "_widths"])
        else:
            out[name] = (np.asarray(z[name], np.float64), np.asarray(z[name + "_dir"], np.int8))
    return out


__all__ = ["NpzStreamWriter", "CsvStepWriter", "CompactEncoder", "decode_compact", "load_steps", "load_npz",
           "COMPACT_FORMAT"]
