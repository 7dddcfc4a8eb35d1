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
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .. import pipeline
from ..errors import GcodeplanError
from ..gcode.sources import cr_line_ends
from ..schema import KIND_DWELL, KIND_NAMES, KIND_WAIT, LIMIT_NAMES

ASSETS = Path(__file__).with_name("viewer_assets")

SPEED_FRAC_BITS = 26          # speeds / accelerations rounded to 2^-26 mm/s (mm/s²)
TEXT_BLOCK_BYTES = 2 << 20    # G-code text is compressed in blocks of about this many bytes
TEXT_ZSTD_LEVEL = 5           # 5: 9.9 MB for the 50 MB corpus file's 49 MB of move lines, 0.25 s in 2 threads
DEFLATE_LEVEL = 4
_READ_CHUNK = 8 << 20


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


class ViewerSink(pipeline.Sink):
    """Collects, piece by piece, the compact per-move columns the viewer needs (about 60 bytes a move
    in memory; the plan is not kept). ``close`` keeps the run's result (reader: layers, features)."""

    def __init__(self):
        self._cols: dict[str, list[np.ndarray]] = {k: [] for k in (
            "t", "vs", "vc", "ve", "acc", "dec", "feed", "x", "y", "z", "line", "kind", "flags", "feature",
            "layer", "limit", "object")}
        self._segs: list[np.ndarray] = []
        self.jerk = 0.0
        self.mode: str | None = None
        self.t_end = 0.0
        self.first_pos = (0.0, 0.0, 0.0)
        self.rows = 0
        self.reader = None            # the run's reader (layers, features, objects), set by close/finish
        self.policy = ""
        self.has_object = False

    def add(self, piece: pipeline.Piece) -> None:
        self.add_rows(piece.moves, piece.plan, piece.first_move, piece.mode,
                      piece.segments if piece.mode == "blend" else None)

    def add_rows(self, m: np.ndarray, p: np.ndarray, first: int, mode: str | None, segs=None) -> None:
        """The same as :meth:`add` for callers that hold (MOVE, PLAN) rows, the first row's global index,
        the planning mode and, for blend plans, the SEGMENT rows of these moves."""
        if len(m) == 0:
            return
        if mode is None:   # callers outside the pipeline: S-curves carry their jerk, blends their pieces
            mode = "scurve" if np.any(p["jerk"] != 0.0) else ("blend" if segs is not None else "trapezoid")
        if self.rows == 0:
            self.first_pos = (float(m["x0"][0]), float(m["y0"][0]), float(m["z0"][0]))
            self.has_object = "object" in m.dtype.names
        self.mode = mode or self.mode
        c = self._cols
        c["t"].append(p["t_start"].copy())
        for name, field in (("vs", "start_v"), ("vc", "cruise_v"), ("ve", "end_v"), ("acc", "accel"),
                            ("dec", "decel")):
            c[name].append(p[field].copy())
        c["feed"].append(m["feed_v"].astype(np.float32))
        for ax in "xyz":
            c[ax].append(m[ax + "1"].astype(np.float32))
        c["line"].append(m["line"].astype(np.int64))
        c["kind"].append(m["kind"].copy())
        c["flags"].append(m["flags"].copy())
        c["feature"].append(m["feature"].astype(np.int16))
        c["layer"].append(m["layer"].astype(np.int32))
        c["limit"].append(p["limit"].copy())
        if self.has_object:
            c["object"].append(m["object"].astype(np.int32))
        jerk = p["jerk"]
        if np.any(jerk != 0.0):
            self.jerk = float(np.max(jerk))
        if segs is not None and len(segs):
            keep = np.zeros(len(segs), dtype=[("t0", "f8"), ("dt", "f8"), ("move", "i8"), ("v", "f8", 4),
                                              ("a", "f8", 4)])
            keep["t0"], keep["dt"], keep["move"] = segs["t0"], segs["dt"], segs["move"]
            for k, ax in enumerate("xyze"):
                keep["v"][:, k] = segs["v" + ax]
                keep["a"][:, k] = segs["a" + ax]
            self._segs.append(keep)
        self.t_end = float(p["t_start"][-1] + p["duration"][-1])
        self.rows = first + len(m)

    def close(self, result: pipeline.RunResult) -> None:
        self.finish(result.reader, result.policy)

    def finish(self, reader, policy: str) -> None:
        """Keep the reader (layer heights, feature and object names) and the policy the plan used."""
        self.reader = reader
        self.policy = policy

    def column(self, name: str) -> np.ndarray:
        parts = self._cols[name]
        return np.concatenate(parts) if parts else np.zeros(0)

    def segments(self) -> np.ndarray | None:
        return np.concatenate(self._segs) if self._segs else None


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


def _layer_bars(layer: np.ndarray, feature: np.ndarray, kind: np.ndarray, dur: np.ndarray,
                n_features: int) -> dict:
    """Time per layer split by feature (s): rows = layers in order, columns = features, then 'none'
    (moves before the first feature comment) and 'waits' (heating, homing: not motion)."""
    if layer.size == 0:
        return {"layers": [], "times": []}
    layers = _sorted_unique(layer)
    li = np.searchsorted(layers, layer)
    col = np.where(feature >= 0, feature.astype(np.int64), n_features)
    col = np.where(kind == KIND_WAIT, n_features + 1, col)
    width = n_features + 2
    times = np.bincount(li * width + col, weights=dur, minlength=len(layers) * width).reshape(len(layers), width)
    return {"layers": layers.tolist(), "times": np.round(times, 6).tolist()}


# ----------------------------------------------------------------------------------------- the page
def collect(source, machine, policy: str | None = None, jerk: float | None = None, strict: bool = False,
            progress=None) -> ViewerSink:
    """Plan ``source`` once into a :class:`ViewerSink` (raises GcodeplanError on bad input)."""
    sink = ViewerSink()
    pipeline.run(source, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink], progress=progress)
    return sink


def viewer_data(sink: ViewerSink, source, machine_name: str = "", policy: str = "") -> dict:
    """Everything the page needs, packed: ``{"meta": {...}, "arrays": {...}, "text": [...]}``.
    ``source``: the path whose lines the inspector shows (read a second time here)."""
    if sink.rows == 0 or sink.reader is None:
        raise GcodeplanError(f"{os.fspath(source) if isinstance(source, (str, os.PathLike)) else source}: "
                             "no moves to show (empty file, or no motion commands)")
    reader = sink.reader
    n = sink.rows
    t = sink.column("t")
    bits = _time_bits(max(sink.t_end, float(t[-1]) if n else 0.0))
    tq = np.rint(np.r_[t, max(sink.t_end, float(t[-1]))] * float(2 ** bits)).astype(np.int64)
    dq = np.diff(tq, prepend=0)
    if np.any(dq < 0):  # the plan's clock never runs backwards; a rounding tie could, by one unit
        dq = np.maximum(dq, 0)
    kind = sink.column("kind").astype(np.uint8)
    vs = _quantize(sink.column("vs"), SPEED_FRAC_BITS)
    ve = _quantize(sink.column("ve"), SPEED_FRAC_BITS)
    line = sink.column("line").astype(np.int64)
    arrays: dict[str, np.ndarray] = {
        "t_lo": (dq & 0xFFFFFFFF).astype(np.uint32),
        "t_hi": (dq >> 32).astype(np.uint32),
        "vs": vs,
        "vc": _quantize(sink.column("vc"), SPEED_FRAC_BITS),
        # the end speed is the next move's start speed but across a full stop: store the difference
        "ve_res": ve - np.r_[vs[1:], 0.0],
        "acc": _quantize(sink.column("acc"), SPEED_FRAC_BITS),
        "dec": _quantize(sink.column("dec"), SPEED_FRAC_BITS),
        "feed": sink.column("feed").astype(np.float32),
        "x": sink.column("x").astype(np.float32),
        "y": sink.column("y").astype(np.float32),
        "z": sink.column("z").astype(np.float32),
        "line_d": np.diff(line, prepend=0).astype(np.int32),
        "kind": kind,
        "flags": sink.column("flags").astype(np.uint8),
        "feature": sink.column("feature").astype(np.int16),
        "layer_d": np.diff(sink.column("layer").astype(np.int64), prepend=0).astype(np.int32),
        "limit": sink.column("limit").astype(np.uint8),
    }
    if sink.has_object:
        arrays["object"] = sink.column("object").astype(np.int32)
    segs = sink.segments() if sink.mode == "blend" else None
    if segs is not None:
        order = np.argsort(segs["move"], kind="stable")
        segs = segs[order]
        counts = np.bincount(segs["move"], minlength=n)[:n]
        sq = np.rint(segs["t0"] * float(2 ** bits)).astype(np.int64)
        arrays["seg_count"] = counts.astype(np.uint32)
        arrays["seg_t0_lo"] = (sq & 0xFFFFFFFF).astype(np.uint32)
        arrays["seg_t0_hi"] = (sq >> 32).astype(np.uint32)
        arrays["seg_dt"] = segs["dt"].astype(np.float64)
        for k, ax in enumerate("xyze"):
            arrays["seg_v" + ax] = np.ascontiguousarray(segs["v"][:, k])
            arrays["seg_a" + ax] = np.ascontiguousarray(segs["a"][:, k])
    # the text of every line that made a row, in line order (the page finds a move's line by bisection)
    wanted = _sorted_unique(line[line > 0])
    identity = getattr(getattr(reader, "source", None), "identity", None)
    blob = _source_lines(source, wanted, identity) if isinstance(source, (str, os.PathLike)) else b""
    blocks = _text_blocks(blob)
    arrays["text_lines_d"] = np.diff(wanted, prepend=0).astype(np.int32)
    dur = np.diff(tq).astype(np.float64) / float(2 ** bits)
    features = list(getattr(reader, "features", []) or [])
    layer_z = [None if z is None or not math.isfinite(z) else float(z) for z in list(reader.layer_z)]
    meta = {
        "format": 1,
        "name": os.path.basename(os.fspath(source)) if isinstance(source, (str, os.PathLike)) else str(source),
        "machine": machine_name,
        "policy": policy or sink.policy,
        "mode": sink.mode or "trapezoid",
        "jerk": sink.jerk,
        "n": n,
        "t_bits": bits,
        "v_bits": SPEED_FRAC_BITS,
        "t_end": float(tq[-1]) / float(2 ** bits),
        "first_pos": list(sink.first_pos),
        "features": features,
        "layer_z": layer_z,
        "objects": _object_names(reader) if sink.has_object else None,
        "limit_names": list(LIMIT_NAMES),
        "kind_names": list(KIND_NAMES),
        "kind_dwell": KIND_DWELL,
        "kind_wait": KIND_WAIT,
        "layer_bars": _layer_bars(sink.column("layer").astype(np.int64), sink.column("feature").astype(np.int64),
                                  kind, dur, len(features)),
        "text_blocks": [c for c, _ in blocks],
    }
    return {"meta": meta, "arrays": _pack_arrays(arrays),
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
