"""Drive the step kernel over a stream of SEGMENT batches, one buffer per stepper.

:class:`StepGenerator` takes SEGMENT arrays batch by batch (as the streaming
planner emits them), turns them into each stepper's polynomial pieces through
the kinematics, and runs :func:`kernel.gen_steps` into a preallocated buffer per
stepper (:func:`kernel.gen_steps_delta` for a delta tower, which solves the carriage
height of the x, y, z pieces itself). A full buffer is handed to ``sink(stepper_index, times, dirs)`` and
reused, so memory stays bounded whatever the file size. The optional
step+dir+step filter and the per-stepper statistics run on the way out.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from ..errors import ConfigError
from ..kinematics import Rail, rails_for, stepper_pieces
from ..machine import SHAPER_TYPES
from . import KLIPPER_SDS_FILTER_T, kernel  # noqa: F401  (re-exported)

DEFAULT_CHUNK_STEPS = 1 << 20
PENDING_ROWS = 16384      # SEGMENT rows gathered before shaping / smoothing them in one go

Sink = Callable[[int, np.ndarray, np.ndarray], None]


class StepGenerator:
    """Exact per-stepper step times for a plan fed in SEGMENT batches.

    ``sds_filter_t``: when set (s), apply Klipper's step+dir+step filter with that
    window before the sink sees the steps. ``stats[i]`` is the running
    :func:`kernel.step_stats` vector of stepper i (after the filter).

    ``settings``: a LIMITS row (e.g. ``machine.limits_row()``) whose input-shaper and
    pressure-advance columns apply when :meth:`feed` is not given the MOVE rows and the
    LIMITS table (with them, each piece takes the settings of its move's LIMITS row, so
    SET_INPUT_SHAPER / SET_PRESSURE_ADVANCE / M900 / M572 act mid-file). Shaping
    (:mod:`.shaping`) turns the pieces of the motors that move with X or Y; pressure
    advance (:mod:`.pressure_advance`) those of a motor that drives E alone; Z and pure
    extruder motors without pressure advance see the planner's pieces untouched.
    """

    def __init__(self, rails: list[Rail], sink: Sink, *, chunk_steps: int = DEFAULT_CHUNK_STEPS,
                 sds_filter_t: float | None = None, settings: np.ndarray | None = None):
        self.rails = list(rails)
        self.sink = sink
        self.sds_filter_t = sds_filter_t
        n = len(self.rails)
        self.states = [kernel.new_state() for _ in range(n)]
        self.stats = [kernel.new_stats() for _ in range(n)]
        self._sds = [np.zeros(kernel.SDS_STATE_LEN) for _ in range(n)]
        self._buf_t = [np.empty(chunk_steps, np.float64) for _ in range(n)]
        self._buf_d = [np.empty(chunk_steps, np.int8) for _ in range(n)]
        self._fill = [0] * n
        self.steps_generated = 0      # before the filter
        self.settings = None if settings is None else np.asarray(settings).reshape(-1)[:1]
        # which motors shaping and pressure advance act on (a delta tower moves with X and Y)
        self._xy_rails = [i for i, r in enumerate(self.rails)
                          if r.tower is not None or (r.weights is not None and (r.weights[0] or r.weights[1]))]
        self._e_rails = [i for i, r in enumerate(self.rails) if r.weights is not None
                         and r.weights[3] and not any(r.weights[:3])]
        self._mixed_e = [r.name for r in self.rails if r.weights is not None and r.weights[3] and any(r.weights[:3])]
        self._other = [i for i in range(n) if i not in self._xy_rails and i not in self._e_rails]
        self._plain = True            # no shaping nor pressure advance met so far: the planner's pieces as they are
        self._sh = _StreamState()
        self._pa = _StreamState()
        self._pending: list[tuple] = []
        self._pending_rows = 0
        self._last_settings = None

    # ---------------------------------------------------------------- settings per piece
    def _piece_settings(self, segments, moves, limits, first_move):
        """(shaper key index per piece, keys, K per piece (0 where Klipper does not advance), h per piece)."""
        n = len(segments)
        if moves is not None and limits is not None and len(moves):
            idx = segments["move"].astype(np.int64)
            if idx.min() >= first_move and idx.max() < first_move + len(moves):
                idx = idx - first_move
            idx = np.clip(idx, 0, len(moves) - 1)
            mv = moves[idx]
            lim = np.asarray(limits)[mv["limits"].astype(np.int64)]
            can_pa = (((mv["x1"] != mv["x0"]) | (mv["y1"] != mv["y0"])) & (mv["e1"] > mv["e0"]))
        else:
            if self.settings is None:
                return None
            lim = np.repeat(self.settings, n)
            # no MOVE rows: a piece advances when it moves X or Y and E rises at its middle (same rule)
            half = 0.5 * segments["dt"]
            xy = np.zeros(n, bool)
            for ax in "xy":
                xy |= (segments["v" + ax] != 0) | (segments["a" + ax] != 0) | (segments["j" + ax] != 0)
            e_rate = segments["ve"] + half * (segments["ae"] + 0.5 * half * segments["je"])
            can_pa = xy & (e_rate > 0)
        if not (np.any(lim["shaper_freq_x"] > 0) or np.any(lim["shaper_freq_y"] > 0) or np.any(lim["pa_k"] != 0)
                or not self._plain):
            return None
        cols = ("shaper_type_x", "shaper_freq_x", "damping_x", "shaper_type_y", "shaper_freq_y", "damping_y")
        raw = np.column_stack([lim[c] for c in cols])
        # an axis with frequency 0 is unshaped whatever its type: one key for all of them
        raw[raw[:, 1] <= 0, 0:3:2] = 0.0
        raw[raw[:, 4] <= 0, 3:6:2] = 0.0
        k_pa = np.where(can_pa, lim["pa_k"], 0.0)
        # Klipper turns the smoothing off with K = 0 (pressure advance off: the nominal position)
        h = np.where(lim["pa_k"] != 0, 0.5 * lim["pa_smooth_t"], 0.0)
        return raw, k_pa, h

    def feed(self, segments: np.ndarray, reset: np.ndarray | None = None, *, moves: np.ndarray | None = None,
             limits: np.ndarray | None = None, first_move: int = 0) -> None:
        """Generate the steps of one batch of SEGMENT rows (in time order, following the previous batch).

        ``reset``: optional uint8 per row, non-zero where the position was set
        just before the row (G28 / SET_KINEMATIC_POSITION) so the grid re-anchors.
        ``moves``/``limits``/``first_move``: the batch's MOVE rows, the LIMITS table and the
        global index of ``moves[0]``, for per-move shaper and pressure-advance settings.
        """
        if len(segments) == 0:
            return
        if reset is None:
            reset = np.zeros(len(segments), np.uint8)
        else:
            reset = np.ascontiguousarray(reset, dtype=np.uint8)
        st = self._piece_settings(segments, moves, limits, first_move)
        if st is None and self._plain:
            cols = None
            for si, rail in enumerate(self.rails):
                if rail.tower is not None:
                    cols = cols or _xyz_columns(segments)
                    self._run_delta(si, *cols, reset)
                    continue
                t0, dt, p, v, a, j = stepper_pieces(segments, rail)
                self._run(si, t0, dt, p, v, a, j, reset)
            return
        self._plain = False
        if st is None:        # settings unknown for this batch: keep the last ones
            last = self._last_settings
            n = len(segments)
            st = (np.repeat(last[0][-1:], n, axis=0), np.zeros(n) if last[1] is None else np.repeat(last[1][-1:], n),
                  np.repeat(last[2][-1:], n))
        self._last_settings = st
        # shaping and smoothing cost a little per call: gather small batches (the planner emits one per
        # full stop) into big ones
        self._pending.append((segments, reset) + tuple(st))
        self._pending_rows += len(segments)
        if self._pending_rows >= PENDING_ROWS:
            self._process_pending()

    def _process_pending(self) -> None:
        if not self._pending:
            return
        parts = self._pending
        self._pending = []
        self._pending_rows = 0
        segments = parts[0][0] if len(parts) == 1 else np.concatenate([p[0] for p in parts])
        reset, raw, k_pa, h = (np.concatenate([p[i] for p in parts]) for i in range(1, 5))
        # runs of equal shaper settings: a new run where any column changes
        changed = np.flatnonzero(np.any(raw[1:] != raw[:-1], axis=1)) + 1
        key_idx = np.zeros(len(raw), np.int64)
        key_idx[changed] = 1
        key_idx = np.cumsum(key_idx)
        keys = raw[np.concatenate(([0], changed))]
        for si in self._other:
            t0, dt, p, v, a, j = stepper_pieces(segments, self.rails[si])
            self._run(si, t0, dt, p, v, a, j, reset)
        if self._xy_rails:
            self._feed_shaped(segments, reset, key_idx, keys)
        if self._e_rails:
            if self._mixed_e and np.any(k_pa != 0):
                raise ConfigError(f"pressure advance on a motor that also moves with X/Y/Z "
                                  f"({', '.join(self._mixed_e)}) is not modelled")
            self._feed_pa(segments, reset, k_pa, h)

    # ---------------------------------------------------------------- input shaping
    def _feed_shaped(self, segments, reset, key_idx, keys):
        from .shaping import ShapedStream, shaper_pulses

        cur = self._sh
        n = len(segments)
        inner = np.flatnonzero((key_idx[1:] != key_idx[:-1]) | (reset[1:] == kernel.RESET_ANCHOR)) + 1
        cuts = [0] + inner.tolist() + [n]
        for i0, i1 in zip(cuts[:-1], cuts[1:]):
            key = tuple(float(x) for x in keys[key_idx[i0]])
            if cur.started and (key != cur.key or reset[i0] == kernel.RESET_ANCHOR):
                self._close_stream(cur, self._xy_rails, shaped=True)
                cur.flag = kernel.RESET_ANCHOR if reset[i0] == kernel.RESET_ANCHOR else kernel.RESET_CONTINUE
            if not cur.started:
                cur.key = key
                cur.started = True
                tx, fx, zx, ty, fy, zy = key if key is not None else (0, 0, 0, 0, 0, 0)
                px = shaper_pulses(_SHAPER_NAMES[int(tx)], fx, zx) if fx > 0 else (np.zeros(0), np.zeros(0))
                py = shaper_pulses(_SHAPER_NAMES[int(ty)], fy, zy) if fy > 0 else (np.zeros(0), np.zeros(0))
                cur.stream = ShapedStream(px, py, start_u=cur.end_u)
                if reset[i0] == kernel.RESET_ANCHOR:
                    cur.flag = kernel.RESET_ANCHOR
            out = cur.stream.feed(segments[i0:i1])
            self._step_group(cur, self._xy_rails, out)

    def _step_group(self, cur, rails, out):
        if len(out) == 0:
            return
        rs = np.zeros(len(out), np.uint8)
        if cur.flag:
            rs[0] = cur.flag
            cur.flag = 0
        cols = None
        for si in rails:
            if self.rails[si].tower is not None:
                # delta: the shaped x, y (and z) pieces through the tower's own kernel
                if cols is None:
                    cols = _xyz_columns(out) if isinstance(out, np.ndarray) else (out.t0, out.dt, out.p, out.v,
                                                                                  out.a, out.j)
                self._run_delta(si, *cols, rs)
                continue
            if isinstance(out, np.ndarray):
                t0, dt, p, v, a, j = stepper_pieces(out, self.rails[si])
            else:
                t0, dt, p, v, a, j = out.rail(self.rails[si].weights)
            self._run(si, t0, dt, p, v, a, j, rs)

    # ---------------------------------------------------------------- pressure advance
    def _feed_pa(self, segments, reset, k_pa, h):
        from .pressure_advance import SmoothedStream

        cur = self._pa
        n = len(segments)
        inner = np.flatnonzero((h[1:] != h[:-1]) | (reset[1:] == kernel.RESET_ANCHOR)) + 1
        cuts = [0] + inner.tolist() + [n]
        for i0, i1 in zip(cuts[:-1], cuts[1:]):
            key = float(h[i0])
            if cur.started and (key != cur.key or reset[i0] == kernel.RESET_ANCHOR):
                self._close_stream(cur, self._e_rails, shaped=False)
                cur.flag = kernel.RESET_ANCHOR if reset[i0] == kernel.RESET_ANCHOR else kernel.RESET_CONTINUE
            part = segments[i0:i1]
            if not cur.started:
                cur.key = key
                cur.started = True
                cur.stream = SmoothedStream(key, start_u=cur.end_u) if key > 0 else None
                if reset[i0] == kernel.RESET_ANCHOR:
                    cur.flag = kernel.RESET_ANCHOR
            if cur.stream is None:
                # no smoothing: the nominal pieces (after a smoothed stretch, from where it ended)
                if np.isfinite(cur.end_u):
                    part = _clip_start(part, cur.end_u)
                self._step_group(cur, self._e_rails, part)
                if len(part):
                    cur.end_u = float(part["t0"][-1] + part["dt"][-1])
                continue
            t0, dt, c = cur.stream.feed(part["t0"], part["dt"], part["pe"], part["ve"], part["ae"], part["je"],
                                        k_pa[i0:i1])
            self._step_poly(cur, t0, dt, c)

    def _step_poly(self, cur, t0, dt, c):
        if len(t0) == 0:
            return
        rs = np.zeros(len(t0), np.uint8)
        if cur.flag:
            rs[0] = cur.flag
            cur.flag = 0
        for si in self._e_rails:
            w = self.rails[si].weights[3]
            coef = c if w == 1.0 else c * w
            self._run_poly(si, t0, dt, np.ascontiguousarray(coef), rs)
        cur.end_u = float(t0[-1] + dt[-1])

    def _close_stream(self, cur, rails, shaped: bool) -> None:
        if cur.stream is not None:
            if shaped:
                out = cur.stream.finish()
                self._step_group(cur, rails, out)
                cur.end_u = cur.stream.end_u
            else:
                t0, dt, c = cur.stream.finish()
                self._step_poly(cur, t0, dt, c)
                cur.end_u = max(cur.end_u, cur.stream.end_u)
        cur.stream = None
        cur.started = False

    # ---------------------------------------------------------------- kernels and buffers
    def _run(self, si, t0, dt, p, v, a, j, reset):
        start = 0
        n_pieces = len(t0)
        step_dist = self.rails[si].step_dist
        while start < n_pieces:
            buf_t = self._buf_t[si]
            buf_d = self._buf_d[si]
            nxt, fill, need = kernel.gen_steps(t0, dt, p, v, a, j, reset, step_dist, self.states[si],
                                               start, buf_t, buf_d, self._fill[si])
            start = self._after_kernel(si, t0, nxt, fill, need, n_pieces)

    def _run_delta(self, si, t0, dt, p, v, a, j, reset):
        """Steps of delta tower ``si`` from pieces with (n, ≥3) x, y, z coefficient columns."""
        start = 0
        n_pieces = len(t0)
        arm2, tx, ty = self.rails[si].tower
        step_dist = self.rails[si].step_dist
        while start < n_pieces:
            nxt, fill, need = kernel.gen_steps_delta(t0, dt, p, v, a, j, reset, arm2, tx, ty, step_dist,
                                                     self.states[si], start, self._buf_t[si], self._buf_d[si],
                                                     self._fill[si])
            if need == -2:
                raise ConfigError(f"{self.rails[si].name}: the arm cannot reach the position at t = {t0[nxt]!r} s "
                                  f"(outside the delta's reach)")
            start = self._after_kernel(si, t0, nxt, fill, need, n_pieces)

    def _run_poly(self, si, t0, dt, coef, reset):
        start = 0
        n_pieces = len(t0)
        step_dist = self.rails[si].step_dist
        while start < n_pieces:
            nxt, fill, need = kernel.gen_steps_poly(t0, dt, coef, reset, step_dist, self.states[si], start,
                                                    self._buf_t[si], self._buf_d[si], self._fill[si])
            start = self._after_kernel(si, t0, nxt, fill, need, n_pieces)

    def _after_kernel(self, si, t0, nxt, fill, need, n_pieces) -> int:
        if need < 0:
            raise RuntimeError(f"{self.rails[si].name}: plan piece at t = {t0[nxt]!r} s has a non-finite "
                               f"coefficient (a planner bug)")
        self.steps_generated += fill - self._fill[si]
        self._fill[si] = fill
        if nxt < n_pieces:          # buffer full
            if fill == 0:             # one piece holds more steps than the buffer: grow it
                size = max(need, 2 * len(self._buf_t[si]))
                self._buf_t[si] = np.empty(size, np.float64)
                self._buf_d[si] = np.empty(size, np.int8)
            else:
                self._flush(si)
        return nxt

    def _flush(self, si: int) -> None:
        fill = self._fill[si]
        if fill == 0:
            return
        times = self._buf_t[si][:fill]
        dirs = self._buf_d[si][:fill]
        if self.sds_filter_t is not None:
            out_t = np.empty(fill, np.float64)
            out_d = np.empty(fill, np.int8)
            m = kernel.sds_filter(times, dirs, self.sds_filter_t, self._sds[si], out_t, out_d)
            times, dirs = out_t[:m], out_d[:m]
        self._emit(si, times, dirs)
        self._fill[si] = 0

    def _emit(self, si: int, times: np.ndarray, dirs: np.ndarray) -> None:
        if len(times):
            kernel.step_stats(times, dirs, self.stats[si])
            self.sink(si, times, dirs)

    def finish(self) -> None:
        """Close the shaped and smoothed streams (the machine at rest after the last piece), then flush
        every buffer (and the step the filter holds back) to the sink."""
        if not self._plain:
            self._process_pending()
            if self._xy_rails:
                self._close_stream(self._sh, self._xy_rails, shaped=True)
            if self._e_rails:
                self._close_stream(self._pa, self._e_rails, shaped=False)
        for si in range(len(self.rails)):
            self._flush(si)
            if self.sds_filter_t is not None:
                t, d = kernel.sds_flush(self._sds[si])
                self._emit(si, t, d)


class _StreamState:
    """One group of motors' current stream (shaped or smoothed) and where its output ends."""

    def __init__(self):
        self.stream = None
        self.key = None
        self.started = False
        self.flag = 0
        self.end_u = -np.inf


_SHAPER_NAMES = SHAPER_TYPES


def _xyz_columns(seg: np.ndarray) -> tuple[np.ndarray, ...]:
    """(t0, dt, p, v, a, j) of SEGMENT rows, p..j as (n, 3) x, y, z columns (the delta kernel's input)."""
    out = [np.ascontiguousarray(seg["t0"], np.float64), np.ascontiguousarray(seg["dt"], np.float64)]
    for prefix in "pvaj":
        out.append(np.ascontiguousarray(np.column_stack([seg[prefix + ax] for ax in "xyz"]), dtype=np.float64))
    return tuple(out)


def _clip_start(part: np.ndarray, u: float) -> np.ndarray:
    """The SEGMENT rows from time ``u`` on (the first row re-based there)."""
    ends = part["t0"] + part["dt"]
    k = int(np.searchsorted(ends, u, side="right"))
    part = part[k:].copy()
    if len(part) and part["t0"][0] < u:
        s = u - part["t0"][0]
        r = part[0]
        for ax in "xyze":
            p, v, a, j = r["p" + ax], r["v" + ax], r["a" + ax], r["j" + ax]
            r["p" + ax] = p + s * (v + s * (0.5 * a + s * j / 6.0))
            r["v" + ax] = v + s * (a + 0.5 * j * s)
            r["a" + ax] = a + j * s
        r["t0"] = u
        r["dt"] = r["dt"] - s
        part[0] = r
    return part


def generate_steps(segments: np.ndarray | Iterable[np.ndarray], machine=None, *, rails: list[Rail] | None = None,
                   kinematics=None, klipper_names: bool = False, sds_filter_t: float | None = None,
                   reset: np.ndarray | None = None, settings: np.ndarray | None = None
                   ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """All step times in memory: {stepper name: (times s, dirs int8)}. For tests and small files.

    ``segments`` is one SEGMENT array or an iterable of batches (``reset`` only
    applies to a single array). Steppers come from ``rails``, else from ``kinematics``
    (a built-in name or an object with ``rails(machine, klipper_names)``, e.g.
    :class:`gcodeplan.kinematics.Linear`), else from the machine. ``settings``: the
    LIMITS row whose input-shaper / pressure-advance columns apply (default: the
    machine's, ``machine.limits_row()``).
    """
    if rails is None:
        rails = rails_for(machine, klipper_names, kinematics=kinematics)
    if settings is None and machine is not None:
        settings = machine.limits_row()
    parts: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in rails]

    def sink(si, t, d):
        parts[si].append((t.copy(), d.copy()))

    gen = StepGenerator(rails, sink, sds_filter_t=sds_filter_t, settings=settings)
    if isinstance(segments, np.ndarray):
        gen.feed(segments, reset)
    else:
        for batch in segments:
            gen.feed(batch)
    gen.finish()
    out = {}
    for rail, chunks in zip(rails, parts):
        if chunks:
            out[rail.name] = (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]))
        else:
            out[rail.name] = (np.empty(0, np.float64), np.empty(0, np.int8))
    return out
