"""The interactive plan viewer: one self-contained HTML page to explore a whole print.

``gcodeplan view FILE -o view.html`` writes it; ``gcodeplan report`` embeds the same viewer above its
tables. The page works offline from disk: the JavaScript (gcodeplan's own ``viewer.js``, uPlot for the
timeline and fzstd for the G-code text, both vendored from npm with their licences in
``viewer_assets/``) and the data are inlined.

What the page holds, per MOVE row (one pass of :func:`gcodeplan.pipeline.run` with :class:`ViewerSink`):

* the plan, exactly enough to evaluate every move's profile in JavaScript in float64: start times on a
  fixed-point grid of 2^-k s (k chosen so the whole print fits in 52 bits: 1.5e-11 s for a 19-hour print),
  stored as integer deltas; start, cruise and end speeds and the accelerations rounded to 2^-26 mm/s
  (1.5e-8 mm/s, 2^-26 mm/s²). The speed the inspector shows is then the plan's within ~1e-8 mm/s; the
  phase times are rebuilt from the speeds (trapezoid: Δv / a, S-curve: the time-optimal jerk-limited
  ramp of docs/design.md), the cruise time from the start of the next move. Blend plans (parabolic
  corners) cannot be rebuilt from PLAN rows: their SEGMENT pieces (velocity and acceleration vectors)
  are stored instead;
* float32 where exactness is not needed: XY(Z) end points for the toolpath, the requested feed;
* small integers: line number (delta-coded), kind, flags, feature, layer, object, what limited the move.

The columns are compressed as the plan streams in (the times and coordinates wait in a temporary file until
the print's length fixes the time grid), so memory stays bounded by the page, not the program. A program of
more than :data:`PAGE_GCODE_BYTES` of G-code gets page rows that each merge ``thin`` consecutive moves
(:func:`thin_for`): the page stays about 30 MB whatever the file's size; times and layer bars stay exact.

Each array is deflated (the coordinates byte-shuffled first); the browser inflates it with its own
``DecompressionStream``. The G-code text of the lines that made moves is read in a second
streaming pass over the source (:func:`_pick_lines`, vectorised per chunk) and stored in zstd blocks of
about 1 MB that the page decodes only when the inspector needs a line of that block: on the 50 MB corpus
file the text is 49 MB, 10.5 MB compressed. zstd compresses G-code text 5× faster than zlib at a better
ratio (0.3 s vs 4 s for the 50 MB file), which is what keeps ``view`` within 3× ``estimate``.
"""
from __future__ import annotations

import base64
import io
import json
import math
import os
import shutil
import tempfile
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .. import pipeline
from ..errors import GcodeplanError
from ..gcode.sources import cr_line_ends
from ..schema import KIND_DWELL, KIND_NAMES, KIND_PRINT, KIND_WAIT, LIMIT_NAMES
from .palette import NO_FEATURE_COLOR, WAITS_COLOR, feature_colors

ASSETS = Path(__file__).with_name("viewer_assets")

SPEED_FRAC_BITS = 26          # speeds / accelerations rounded to 2^-26 mm/s (mm/s²)
TEXT_BLOCK_BYTES = 2 << 20    # G-code text is compressed in blocks of about this many bytes
TEXT_ZSTD_LEVEL = 5           # 5: 9.9 MB for the 50 MB corpus file's 49 MB of move lines, 0.25 s in 2 threads
DEFLATE_LEVEL = 4
_READ_CHUNK = 8 << 20
SPILL_CHUNK_ROWS = 1 << 20    # rows read back at a time from a column kept in a temporary file


def _sorted_unique(a: np.ndarray) -> np.ndarray:
    """np.unique for arrays that are almost always sorted already (line and layer numbers): one pass."""
    if a.size and np.any(a[1:] < a[:-1]):
        a = np.sort(a)
    return a[np.r_[True, a[1:] != a[:-1]]] if a.size else a


def _time_bits(t_end: float) -> int:
    """Fraction bits of the fixed-point time grid: the whole print in 52 bits, between 2^-20 and 2^-40 s."""
    if not (t_end > 0.0 and math.isfinite(t_end)):
        return 40
    return int(min(40, max(20, 52 - math.ceil(math.log2(t_end + 1.0)))))


class _Stream:
    """One page array compressed as it grows (zlib format, as the page inflates it): only the compressed
    bytes are kept."""

    __slots__ = ("dtype", "n", "_z", "_out")

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.n = 0
        self._z = zlib.compressobj(DEFLATE_LEVEL)
        self._out: list[bytes] = []

    def add(self, a: np.ndarray) -> None:
        a = np.ascontiguousarray(a, dtype=self.dtype)
        self.n += len(a)
        if a.size:
            self._out.append(self._z.compress(a.tobytes()))

    def add_bytes(self, b: bytes, count: int = 0) -> None:
        self.n += count
        if b:
            self._out.append(self._z.compress(b))

    def packed(self, shuffle: bool = False) -> dict:
        blob = b"".join(self._out) + self._z.flush()
        self._out = []
        return {"dtype": _DTYPES[self.dtype], "n": int(self.n), "shuffle": int(shuffle),
                "b64": base64.b64encode(blob).decode("ascii")}


class _Spill:
    """A column kept on disk (an unnamed temporary file) until the page is packed: times, whose grid is
    chosen from the print's length (known at the end), and the coordinates, byte-shuffled as a whole."""

    __slots__ = ("dtype", "n", "_fh")

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.n = 0
        self._fh = None

    def add(self, a: np.ndarray) -> None:
        if self._fh is None:
            self._fh = tempfile.TemporaryFile(prefix="gcodeplan-view-")
        a = np.ascontiguousarray(a, dtype=self.dtype)
        self._fh.write(a.tobytes())
        self.n += len(a)

    def chunks(self, rows: int = SPILL_CHUNK_ROWS):
        """The column again, in order, ``rows`` at a time."""
        if self._fh is None:
            return
        self._fh.seek(0)
        size = self.dtype.itemsize
        while True:
            b = self._fh.read(rows * size)
            if not b:
                return
            yield np.frombuffer(b, self.dtype)

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


class _LayerBars:
    """Time per (group, feature) in s, folded chunk by chunk (bincount): the page's layer bars."""

    def __init__(self):
        self.t = np.zeros((0, 0))
        self.seen = np.zeros(0, bool)

    def add(self, group: np.ndarray, feature: np.ndarray, kind: np.ndarray, dur: np.ndarray) -> None:
        if group.size == 0:
            return
        row = group.astype(np.int64) + 1                 # group -1 (before the first layer) is row 0
        n_rows = max(self.t.shape[0], int(row.max()) + 1)
        n_feat = max(self.t.shape[1] - 2, int(feature.max()) + 1, 0)
        width = n_feat + 2
        if (n_rows, width) != self.t.shape:
            grown = np.zeros((n_rows, width))
            old_f = max(self.t.shape[1] - 2, 0)
            if self.t.size:
                grown[: self.t.shape[0], :old_f] = self.t[:, :old_f]
                grown[: self.t.shape[0], -2:] = self.t[:, -2:]
            self.t = grown
            seen = np.zeros(n_rows, bool)
            seen[: self.seen.size] = self.seen
            self.seen = seen
        col = np.where(feature >= 0, feature.astype(np.int64), n_feat)
        col = np.where(kind == KIND_WAIT, n_feat + 1, col)
        self.t += np.bincount(row * width + col, weights=dur, minlength=n_rows * width).reshape(n_rows, width)
        self.seen[np.unique(row)] = True

    def meta(self, n_features: int) -> dict:
        """{"layers": groups in order, "times": per group, columns = features, then 'none', then 'waits'}."""
        rows = np.flatnonzero(self.seen)
        if rows.size == 0:
            return {"layers": [], "times": []}
        n_feat = self.t.shape[1] - 2
        out = np.zeros((rows.size, n_features + 2))
        k = min(n_feat, n_features)
        out[:, :k] = self.t[rows, :k]
        out[:, n_features] = self.t[rows, n_feat] + self.t[rows, k:n_feat].sum(axis=1)
        out[:, n_features + 1] = self.t[rows, n_feat + 1]
        return {"layers": (rows - 1).tolist(), "times": np.round(out, 6).tolist()}


#: moves a CNC program's Z levels are grouped by: a new level at each feed move at a new height (1 µm)
Z_LEVEL_UM = 1.0
#: more Z levels than this (3-D contouring, a vase) are not levels: such a program stays one group
MAX_Z_LEVELS = 2000
#: planning modes whose SEGMENT pieces the page keeps (their rows are not trapezoids the page can rebuild)
SEGMENT_MODES = ("blend", "linuxcnc")


class ViewerSink(pipeline.Sink):
    """Packs, piece by piece, the compact per-move columns the viewer needs: each column is compressed as
    it grows (about 6 bytes a move kept in memory for a print; the plan is not kept), and the times and
    coordinates wait in a temporary file until the page is packed. ``close`` keeps the run's result
    (reader: layers, features)."""

    def __init__(self, thin: int = 1):
        self.thin = max(1, int(thin))     # page rows merge this many moves (:func:`thin_for`)
        self.moves = 0                    # moves seen (rows × thin, but for the last row)
        self._carry = None                # the moves of an unfinished group of ``thin`` (thinned pages)
        self._z = {name: _Stream(dt) for name, dt in (
            ("vs", "f8"), ("vc", "f8"), ("ve_res", "f8"), ("acc", "f8"), ("dec", "f8"), ("feed", "f4"),
            ("z", "f4"), ("line_d", "i4"), ("kind", "u1"), ("flags", "u1"), ("feature", "i2"),
            ("layer_d", "i4"), ("zlevel_d", "i4"), ("limit", "u1"), ("object", "i4"))}
        self._spill = {name: _Spill(dt) for name, dt in (("t", "f8"), ("x", "f4"), ("y", "f4"), ("line", "i8"))}
        self._seg = None                  # SEGMENT columns (blend and LinuxCNC plans), made on first use
        self._seg_t0 = _Spill("f8")
        self._bars = _LayerBars()
        self._zbars = _LayerBars()
        self._ve_tail = None              # the last row's end speed, until the next row's start speed is known
        self._line_prev = 0
        self._layer_prev = 0
        self._zlevel_prev = 0
        self._zlevels: dict[int, int] = {}    # Z level (µm) -> group, in order of first use
        self._zlevel_z: list[float] = []
        self._zlevel_cur = -1
        self._max_layer = -1
        self._printed = False             # any move extruded: a printer's program, not a CNC one
        self.jerk = 0.0
        self.mode: str | None = None
        self.t_end = 0.0
        self.first_pos = (0.0, 0.0, 0.0)
        self.rows = 0
        self.reader = None            # the run's reader (layers, features, objects), set by close/finish
        self.policy = ""
        self.has_object = False

    def add(self, piece: pipeline.Piece) -> None:
        own = piece.mode in SEGMENT_MODES
        self.add_rows(piece.moves, piece.plan, piece.first_move, piece.mode, piece.segments if own else None)

    def add_rows(self, m: np.ndarray, p: np.ndarray, first: int, mode: str | None, segs=None) -> None:
        """The same as :meth:`add` for callers that hold (MOVE, PLAN) rows, the first row's global index,
        the planning mode and, for blend and LinuxCNC plans, the SEGMENT rows of these moves."""
        if len(m) == 0:
            return
        if mode is None:   # callers outside the pipeline: S-curves carry their jerk, blends their pieces
            mode = "scurve" if np.any(p["jerk"] != 0.0) else ("blend" if segs is not None else "trapezoid")
        self.moves += len(m)
        if self.thin > 1:
            # the layer bars from the moves themselves; the rest from rows of ``thin`` moves each
            self._bars.add(m["layer"].astype(np.int64), m["feature"].astype(np.int16), m["kind"], p["duration"])
            self.mode = mode or self.mode
            merged = self._merge(m, p)
            if merged is not None:
                self._add_exact(merged[0], merged[1], self.rows, mode, None)
            return
        self._add_exact(m, p, first, mode, segs)

    def _merge(self, m: np.ndarray, p: np.ndarray, final: bool = False):
        """(MOVE, PLAN) rows each standing for ``thin`` consecutive moves (the rest waits for the next call):
        the first move's start, the last one's end, the highest cruise speed, feed and accelerations, the
        summed duration; a print row when any of them printed."""
        if self._carry is not None:
            m = np.concatenate([self._carry[0], m])
            p = np.concatenate([self._carry[1], p])
            self._carry = None
        k = self.thin
        full = len(m) if final else len(m) // k * k
        if full < len(m):
            self._carry = (m[full:].copy(), p[full:].copy())
        if full == 0:
            return None
        m, p = m[:full], p[:full]
        starts = np.arange(0, full, k)
        last = np.r_[starts[1:], full] - 1
        mm, pp = m[starts].copy(), p[starts].copy()
        for f in ("x1", "y1", "z1", "e1"):
            mm[f] = m[f][last]
        mm["feed_v"] = np.maximum.reduceat(m["feed_v"], starts)
        printed = np.maximum.reduceat((m["kind"] == KIND_PRINT).astype(np.int8), starts) > 0
        mm["kind"] = np.where(printed, KIND_PRINT, m["kind"][starts])
        mm["flags"] = np.bitwise_or.reduceat(m["flags"], starts)
        mm["move_d"] = np.add.reduceat(m["move_d"], starts)
        pp["duration"] = np.add.reduceat(p["duration"], starts)
        pp["end_v"] = p["end_v"][last]
        for f in ("cruise_v", "accel", "decel"):
            pp[f] = np.maximum.reduceat(p[f], starts)
        pp["jerk"] = 0.0                  # rows of several moves are drawn as trapezoids
        return mm, pp

    def _add_exact(self, m: np.ndarray, p: np.ndarray, first: int, mode: str | None, segs=None) -> None:
        if self.rows == 0:
            self.first_pos = (float(m["x0"][0]), float(m["y0"][0]), float(m["z0"][0]))
            self.has_object = "object" in m.dtype.names
        self.mode = mode or self.mode
        z, sp = self._z, self._spill
        sp["t"].add(p["t_start"])
        vs = _quantize(p["start_v"], SPEED_FRAC_BITS)
        ve = _quantize(p["end_v"], SPEED_FRAC_BITS)
        z["vs"].add(vs)
        z["vc"].add(_quantize(p["cruise_v"], SPEED_FRAC_BITS))
        # the end speed is the next move's start speed but across a full stop: store the difference
        if self._ve_tail is not None:
            z["ve_res"].add(np.array([self._ve_tail - vs[0]]))
        z["ve_res"].add(ve[:-1] - vs[1:])
        self._ve_tail = float(ve[-1])
        z["acc"].add(_quantize(p["accel"], SPEED_FRAC_BITS))
        z["dec"].add(_quantize(p["decel"], SPEED_FRAC_BITS))
        z["feed"].add(m["feed_v"].astype(np.float32))
        sp["x"].add(m["x1"].astype(np.float32))
        sp["y"].add(m["y1"].astype(np.float32))
        z["z"].add(m["z1"].astype(np.float32))
        line = m["line"].astype(np.int64)
        z["line_d"].add(np.diff(line, prepend=self._line_prev).astype(np.int32))
        self._line_prev = int(line[-1])
        used = line[line > 0]
        if used.size:
            used = used[np.r_[True, used[1:] != used[:-1]]]
            sp["line"].add(used)
        kind = m["kind"]
        self._printed = self._printed or bool(np.any(kind == KIND_PRINT))
        z["kind"].add(kind.astype(np.uint8))
        z["flags"].add(m["flags"].astype(np.uint8))
        feature = m["feature"].astype(np.int16)
        z["feature"].add(feature)
        layer = m["layer"].astype(np.int64)
        z["layer_d"].add(np.diff(layer, prepend=self._layer_prev).astype(np.int32))
        self._layer_prev = int(layer[-1])
        self._max_layer = max(self._max_layer, int(layer.max()))
        z["limit"].add(p["limit"].astype(np.uint8))
        if self.has_object:
            z["object"].add(m["object"].astype(np.int32))
        dur = p["duration"]
        if self.thin == 1:
            self._bars.add(layer, feature, kind, dur)
        if self._max_layer < 0 and len(self._zlevels) <= MAX_Z_LEVELS:
            zl = self._z_levels(m)
        else:                         # a print (it has layers), or no plain Z levels: nothing to group
            zl = np.full(len(m), self._zlevel_prev, np.int64)
        z["zlevel_d"].add(np.diff(zl, prepend=self._zlevel_prev).astype(np.int32))
        self._zlevel_prev = int(zl[-1])
        self._zbars.add(zl, feature, kind, dur)
        jerk = p["jerk"]
        if np.any(jerk != 0.0):
            self.jerk = float(np.max(jerk))
        if segs is not None:
            self._add_segments(segs, first, len(m))
        self.t_end = float(p["t_start"][-1] + p["duration"][-1])
        self.rows = first + len(m)

    def _z_levels(self, m: np.ndarray) -> np.ndarray:
        """Group of each move by Z level, for programs without layers (CNC): the height of the latest feed
        move (to 1 µm), groups numbered in the order the program first cuts at them; moves before the
        first feed move belong to its level."""
        from ..schema import FLAG_RAPID, KIND_TRAVEL

        # the cuts: feed moves (G1/G2/G3, not G0 rapids) of a program that does not extrude
        feed = (m["kind"] == KIND_PRINT) | ((m["kind"] == KIND_TRAVEL) & ((m["flags"] & FLAG_RAPID) == 0))
        out = np.empty(len(m), np.int64)
        if not feed.any():
            out[:] = self._zlevel_cur
            return out
        zk = np.rint(m["z1"][feed] * (1000.0 / Z_LEVEL_UM)).astype(np.int64)
        # group ids of the distinct heights in first-use order (few: one dict look-up per new height run)
        ids = np.empty(zk.size, np.int64)
        starts = np.flatnonzero(np.r_[True, zk[1:] != zk[:-1]])
        ends = np.r_[starts[1:], zk.size]
        for a, b in zip(starts.tolist(), ends.tolist()):
            key = int(zk[a])
            g = self._zlevels.get(key)
            if g is None:
                g = self._zlevels[key] = len(self._zlevels)
                self._zlevel_z.append(key * Z_LEVEL_UM / 1000.0)
            ids[a:b] = g
        pos = np.flatnonzero(feed)
        last = np.maximum.accumulate(np.where(feed, np.arange(len(m)), -1))
        k = np.searchsorted(pos, last.clip(min=0))
        out = np.where(last >= 0, ids[np.minimum(k, ids.size - 1)], self._zlevel_cur)
        if self._zlevel_cur < 0:      # before the program's first feed move: the first level
            out[out < 0] = ids[0]
        self._zlevel_cur = int(out[-1])
        return out

    def _add_segments(self, segs: np.ndarray, first: int, n: int) -> None:
        if self._seg is None:
            self._seg = {"seg_count": _Stream("u4"), "seg_dt": _Stream("f8")}
            for ax in "xyze":
                self._seg["seg_v" + ax] = _Stream("f8")
                self._seg["seg_a" + ax] = _Stream("f8")
            if self.rows:                # moves before this piece had none
                self._seg["seg_count"].add(np.zeros(self.rows, np.uint32))
        move = np.clip(segs["move"] - first, 0, n - 1)
        order = np.argsort(move, kind="stable")
        s = segs[order]
        self._seg["seg_count"].add(np.bincount(move, minlength=n)[:n].astype(np.uint32))
        self._seg_t0.add(s["t0"])
        self._seg["seg_dt"].add(s["dt"].astype(np.float64))
        for ax in "xyze":
            self._seg["seg_v" + ax].add(s["v" + ax].astype(np.float64))
            self._seg["seg_a" + ax].add(s["a" + ax].astype(np.float64))

    def close(self, result: pipeline.RunResult) -> None:
        self.finish(result.reader, result.policy)

    def finish(self, reader, policy: str) -> None:
        """Keep the reader (layer heights, feature and object names) and the policy the plan used."""
        self.reader = reader
        self.policy = policy

    @property
    def grouped_by_z(self) -> bool:
        """True for a program without layers (a CNC program) that cuts at some height: the page groups its
        moves by Z level instead of showing one 'before the first layer' group."""
        return self._max_layer < 0 and 0 < len(self._zlevels) <= MAX_Z_LEVELS

    def flush(self) -> None:
        """A thinned page's last, shorter row (the moves of an unfinished group)."""
        if self._carry is not None:
            m, p = self._carry
            self._carry = None
            merged = self._merge(m, p, final=True)
            if merged is not None:
                self._add_exact(merged[0], merged[1], self.rows, self.mode, None)

    def line_numbers(self) -> np.ndarray:
        """The sorted distinct source lines that made rows (the lines whose text the page shows)."""
        parts = list(self._spill["line"].chunks())
        return _sorted_unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def pack(self) -> tuple[dict, dict, int]:
        """(arrays packed for the page, layer bars, time grid bits): reads the spilled columns back."""
        self.flush()
        bits = _time_bits(self.t_end)
        scale = float(2 ** bits)
        arrays: dict[str, dict] = {}
        lo, hi = _Stream("u4"), _Stream("u4")
        prev = 0
        for t in self._spill["t"].chunks():
            tq = np.rint(t * scale).astype(np.int64)
            dq = np.maximum(np.diff(tq, prepend=prev), 0)   # a rounding tie never runs the clock backwards
            prev = int(tq[-1])
            lo.add((dq & 0xFFFFFFFF).astype(np.uint32))
            hi.add((dq >> 32).astype(np.uint32))
        end_q = max(int(np.rint(self.t_end * scale)), prev)
        lo.add(np.array([(end_q - prev) & 0xFFFFFFFF], np.uint32))
        hi.add(np.array([(end_q - prev) >> 32], np.uint32))
        arrays["t_lo"], arrays["t_hi"] = lo.packed(), hi.packed()
        z = self._z
        z["ve_res"].add(np.array([(self._ve_tail or 0.0) - 0.0]))
        for name in ("vs", "vc", "ve_res", "acc", "dec", "feed"):
            arrays[name] = z[name].packed()
        for name in ("x", "y"):            # byte-shuffled as a whole: byte plane by byte plane
            col = self._spill[name]
            st = _Stream(col.dtype)
            size = col.dtype.itemsize
            for plane in range(size):
                for a in col.chunks():
                    st.add_bytes(np.ascontiguousarray(a.view(np.uint8).reshape(-1, size)[:, plane]).tobytes())
            st.n = col.n
            arrays[name] = st.packed(shuffle=True)
        arrays["z"] = z["z"].packed()
        for name in ("line_d", "kind", "flags", "feature"):
            arrays[name] = z[name].packed()
        arrays["layer_d"] = z["zlevel_d" if self.grouped_by_z else "layer_d"].packed()
        arrays["limit"] = z["limit"].packed()
        if self.has_object:
            arrays["object"] = z["object"].packed()
        if self._seg is not None:
            seg = self._seg
            lo, hi = _Stream("u4"), _Stream("u4")
            for t in self._seg_t0.chunks():
                sq = np.rint(t * scale).astype(np.int64)
                lo.add((sq & 0xFFFFFFFF).astype(np.uint32))
                hi.add((sq >> 32).astype(np.uint32))
            arrays["seg_count"] = seg["seg_count"].packed()
            arrays["seg_t0_lo"], arrays["seg_t0_hi"] = lo.packed(), hi.packed()
            for name in ["seg_dt"] + [f"seg_{q}{ax}" for q in "va" for ax in "xyze"]:
                arrays[name] = seg[name].packed()
        features = list(getattr(self.reader, "features", []) or [])
        bars = (self._zbars if self.grouped_by_z else self._bars).meta(len(features))
        for col in list(self._spill.values()) + [self._seg_t0]:
            col.close()
        return arrays, bars, bits


# ----------------------------------------------------------------------------------------- G-code text
def _pick_lines(stream, wanted: np.ndarray) -> bytes:
    """The lines numbered ``wanted`` (1-based, sorted, unique) of a binary stream, each ending in ``\\n``
    (a ``\\r`` before it dropped), in order. Vectorised per chunk: a byte mask repeated from a mask of
    the chunk's lines."""
    out: list[bytes] = []
    rest = b""
    line0 = 1
    w = 0
    nw = len(wanted)
    while w < nw:
        chunk = stream.read(_READ_CHUNK)
        final = not chunk
        buf = rest + chunk if chunk else rest + b"\n"
        if final and not rest:
            break
        if buf.find(b"\r") >= 0:        # CR-only line ends count as the reader counts them
            buf = bytearray(buf)
            cr_line_ends(buf, 0, len(buf), final)
            buf = bytes(buf)
        arr = np.frombuffer(buf, np.uint8)
        nl = np.flatnonzero(arr == 10)
        if nl.size == 0:
            rest = buf
            continue
        cut = int(nl[-1]) + 1
        rest = buf[cut:]
        n_lines = nl.size
        hi = np.searchsorted(wanted, line0 + n_lines, side="left")
        if hi > w:
            keep_line = np.zeros(n_lines, bool)
            keep_line[wanted[w:hi] - line0] = True
            body = arr[:cut]
            lengths = np.diff(nl, prepend=-1)          # bytes of each line, its newline included
            mask = np.repeat(keep_line, lengths)
            before = nl[nl > 0] - 1          # a CR just before a newline is not part of the text
            mask[before[body[before] == 13]] = False
            out.append(body[mask].tobytes())
            w = hi
        line0 += n_lines
        if final:
            break
    missing = nw - w
    if missing > 0:          # lines the reader counted past the end (no final newline): empty texts
        out.append(b"\n" * missing)
    return b"".join(out)


def _text_blocks(blob: bytes) -> list[tuple[int, bytes]]:
    """(line count, zstd frame) blocks of about TEXT_BLOCK_BYTES, cut at line ends."""
    import zstandard

    if not blob:
        return []
    arr = np.frombuffer(blob, np.uint8)
    nl = np.flatnonzero(arr == 10)
    ends = np.searchsorted(nl, np.arange(TEXT_BLOCK_BYTES, len(blob), TEXT_BLOCK_BYTES), side="left")
    ends = np.unique(np.r_[ends, nl.size - 1])
    bounds, counts = [], []
    prev_byte, prev_line = 0, 0
    for e in ends.tolist():
        end_byte = int(nl[e]) + 1
        bounds.append((prev_byte, end_byte))
        counts.append(e + 1 - prev_line)
        prev_byte, prev_line = end_byte, e + 1

    def comp(b):
        return zstandard.ZstdCompressor(level=TEXT_ZSTD_LEVEL).compress(blob[b[0]:b[1]])

    with ThreadPoolExecutor(max_workers=2) as pool:
        frames = list(pool.map(comp, bounds))
    return list(zip(counts, frames))


def _source_lines(path: str, wanted: np.ndarray, identity: tuple | None = None) -> bytes:
    """``identity``: the planning pass's (:attr:`gcodeplan.gcode.sources.Source.identity`): the texts must
    come from the very file that was planned."""
    from ..gcode.sources import open_source

    src = open_source(path, identity=identity)
    try:
        stream = io.BufferedReader(src.stream, 1 << 20) if not hasattr(src.stream, "read") else src.stream
        # binary G-code: MOVE line numbers are those of its ASCII conversion, which writes `first_line`
        # lines (metadata, thumbnails) before the G-code the stream yields (gcode/bgcode.py)
        first = int(getattr(src.stream, "first_line", 0) or 0)
        before = int(np.count_nonzero(wanted <= first))
        text = b"\n" * before + _pick_lines(stream, wanted[before:] - first)
        src.check_unchanged()        # the reading may stop before the end: unchanged up to now
        return text
    finally:
        src.close()


# ----------------------------------------------------------------------------------------- packing
_DTYPES = {np.dtype("f8"): "f64", np.dtype("f4"): "f32", np.dtype("u4"): "u32", np.dtype("i4"): "i32",
           np.dtype("i2"): "i16", np.dtype("u1"): "u8"}


# Arrays stored byte-shuffled: float32 coordinates, whose high bytes repeat from move to move. The
# quantized speeds and the time deltas deflate better as they are (measured on the corpus), and then
# need no unshuffling in the page.
SHUFFLED = frozenset({"x", "y"})


def _shuffle(a: np.ndarray) -> bytes:
    """Bytes of equal significance together (as Blosc's shuffle filter)."""
    if a.dtype.itemsize == 1:
        return a.tobytes()
    return np.ascontiguousarray(a.view(np.uint8).reshape(len(a), a.dtype.itemsize).T).tobytes()


def _quantize(v: np.ndarray, bits: int) -> np.ndarray:
    """Round to multiples of 2^-bits (float64, exact)."""
    scale = float(2 ** bits)
    return np.rint(np.asarray(v, np.float64) * scale) / scale


def _pack_arrays(arrays: dict[str, np.ndarray]) -> dict[str, dict]:
    """name -> {dtype, n, shuffle, b64}: each array (shuffled when in SHUFFLED) deflated (zlib format),
    in two threads."""
    names = list(arrays)

    def comp(name):
        a = np.ascontiguousarray(arrays[name])
        return zlib.compress(_shuffle(a) if name in SHUFFLED else a.tobytes(), DEFLATE_LEVEL)

    with ThreadPoolExecutor(max_workers=2) as pool:
        blobs = list(pool.map(comp, names))
    return {name: {"dtype": _DTYPES[np.dtype(arrays[name].dtype)], "n": int(len(arrays[name])),
                   "shuffle": int(name in SHUFFLED),
                   "b64": base64.b64encode(blob).decode("ascii")} for name, blob in zip(names, blobs)}


def _object_names(reader) -> list[str]:
    """Object names the reader found (EXCLUDE_OBJECT, M486, slicer labels), if it tracks them."""
    for holder in (reader, getattr(reader, "interp", None), getattr(reader, "_interp", None)):
        objs = getattr(holder, "objects", None) if holder is not None else None
        if objs is None:
            continue
        names = getattr(objs, "names", objs)
        try:
            return [str(n) for n in names]
        except TypeError:
            continue
    return []


# ----------------------------------------------------------------------------------------- the page
def collect(source, machine, policy: str | None = None, jerk: float | None = None, strict: bool = False,
            progress=None) -> ViewerSink:
    """Plan ``source`` once into a :class:`ViewerSink` (raises GcodeplanError on bad input)."""
    sink = ViewerSink(thin_for(source))
    pipeline.run(source, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink], progress=progress)
    return sink


#: G-code bytes a page holds every move of; a bigger file's page merges consecutive moves into one row, so
#: that the page stays under about 30 MB (12.5 bytes a move, ~29 bytes of G-code a move in a print)
PAGE_GCODE_BYTES = 64 << 20


def thin_for(source) -> int:
    """Moves per page row for ``source``: 1 up to :data:`PAGE_GCODE_BYTES` of G-code, then enough to keep
    the page about that size (compressed and binary G-code count 3× and 5× their bytes)."""
    size = pipeline._file_size(source)
    if size is None:
        return 1
    try:
        with open(source, "rb") as f:
            head = f.read(4)
    except OSError:
        return 1
    if head[:2] == b"\x1f\x8b":
        size *= 3
    elif head == b"GCDE":
        size *= 5
    return max(1, math.ceil(size / PAGE_GCODE_BYTES))


def viewer_data(sink: ViewerSink, source, machine_name: str = "", policy: str = "") -> dict:
    """Everything the page needs, packed: ``{"meta": {...}, "arrays": {...}, "text": [...]}``.
    ``source``: the path whose lines the inspector shows (read a second time here)."""
    sink.flush()
    if sink.rows == 0 or sink.reader is None:
        raise GcodeplanError(f"{os.fspath(source) if isinstance(source, (str, os.PathLike)) else source}: "
                             "no moves to show (empty file, or no motion commands)")
    reader = sink.reader
    n = sink.rows
    # the text of every line that made a row, in line order (the page finds a move's line by bisection)
    wanted = sink.line_numbers()
    arrays, bars, bits = sink.pack()
    identity = getattr(getattr(reader, "source", None), "identity", None)
    blob = _source_lines(source, wanted, identity) if isinstance(source, (str, os.PathLike)) else b""
    blocks = _text_blocks(blob)
    del blob
    arrays.update(_pack_arrays({"text_lines_d": np.diff(wanted, prepend=0).astype(np.int32)}))
    features = list(getattr(reader, "features", []) or [])
    layer_z = [None if z is None or not math.isfinite(z) else float(z) for z in list(reader.layer_z)]
    meta = {
        "format": 1,
        "name": os.path.basename(os.fspath(source)) if isinstance(source, (str, os.PathLike)) else str(source),
        "machine": machine_name,
        "policy": policy or sink.policy,
        "mode": sink.mode or "trapezoid",
        "segments": sink.mode in SEGMENT_MODES and sink.thin == 1,
        "jerk": sink.jerk if sink.thin == 1 else 0.0,
        "n": n,
        "thin": sink.thin,
        "moves": sink.moves,
        "t_bits": bits,
        "v_bits": SPEED_FRAC_BITS,
        "t_end": float(np.rint(sink.t_end * float(2 ** bits))) / float(2 ** bits),
        "first_pos": list(sink.first_pos),
        "features": features,
        "feature_colors": feature_colors(features) + [NO_FEATURE_COLOR, WAITS_COLOR],
        "layer_z": layer_z,
        "cnc": not sink._printed,
        "group_by": "z" if sink.grouped_by_z else "layer",
        "group_z": list(sink._zlevel_z) if sink.grouped_by_z else [],
        "objects": _object_names(reader) if sink.has_object else None,
        "limit_names": list(LIMIT_NAMES),
        "kind_names": list(KIND_NAMES),
        "kind_dwell": KIND_DWELL,
        "kind_wait": KIND_WAIT,
        "layer_bars": bars,
        "text_blocks": [c for c, _ in blocks],
    }
    return {"meta": meta, "arrays": arrays,
            "text": [base64.b64encode(frame).decode("ascii") for _, frame in blocks]}


def _asset(name: str) -> str:
    return (ASSETS / name).read_text(encoding="utf-8")


def _script_safe(js: str) -> str:
    """Inline script text: ``</`` cannot end the element early once written ``<\\/`` (same string in JS)."""
    return js.replace("</", "<\\/")


def viewer_fragment(data: dict) -> str:
    """The viewer as an HTML fragment (styles, markup, data and scripts) to place in any page's body."""
    meta = json.dumps(data["meta"], separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    parts = [f"<style>{_asset('uPlot.min.css')}\n{_asset('viewer.css')}</style>",
             _asset("viewer.html"),
             f'<script type="application/json" id="gpv-meta">{meta}</script>']
    for name, a in data["arrays"].items():
        parts.append(f'<script type="application/octet-stream" id="gpv-a-{name}" data-dtype="{a["dtype"]}" '
                     f'data-n="{a["n"]}" data-shuffle="{a["shuffle"]}">{a["b64"]}</script>')
    for k, b64 in enumerate(data["text"]):
        parts.append(f'<script type="application/octet-stream" id="gpv-text-{k}">{b64}</script>')
    for js in ("uPlot.iife.min.js", "fzstd.umd.js", "viewer.js"):
        parts.append(f"<script>{_script_safe(_asset(js))}</script>")
    return "\n".join(parts)


def viewer_page(data: dict, title: str) -> str:
    """A whole standalone page around :func:`viewer_fragment`."""
    from .html import esc

    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{esc(title)}</title></head><body class=\"gpv-page\">\n"
            f"{viewer_fragment(data)}\n</body></html>\n")


def build_viewer(source, machine, policy: str | None = None, jerk: float | None = None, strict: bool = False,
                 progress=None, title: str | None = None) -> str:
    """Plan ``source`` (path, ``-``, FIFO, file object or line iterable) and return the viewer page (HTML
    text). A source that cannot be read twice is copied once to a temporary file (removed at the end).
    Raises :class:`GcodeplanError` for bad input and for a program without moves."""
    from ..gcode.sources import source_name, spooled

    with spooled(source) as path:
        sink = collect(path, machine, policy, jerk, strict, progress)
        data = viewer_data(sink, path, machine.name, policy or machine.junction_policy)
    data["meta"]["name"] = os.path.basename(source_name(source))
    name = data["meta"]["name"]
    return viewer_page(data, title or f"gcodeplan view: {name}")


__all__ = ["ViewerSink", "collect", "viewer_data", "viewer_fragment", "viewer_page", "build_viewer"]
