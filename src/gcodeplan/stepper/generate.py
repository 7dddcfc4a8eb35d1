"""Drive the step kernel over a stream of SEGMENT batches, one buffer per stepper.

:class:`StepGenerator` takes SEGMENT arrays batch by batch (as the streaming
planner emits them), turns them into each stepper's polynomial pieces through
the kinematics, and runs :func:`kernel.gen_steps` into a preallocated buffer per
stepper (:func:`kernel.gen_steps_delta` for a delta tower, which solves the carriage
height of the x, y, z pieces itself). A full buffer is handed to ``sink(stepper_index, times, dirs)`` and
reused, so memory stays bounded whatever the file size. The optional
step+dir+step filter and the per-stepper statistics run on the way out.

Motors whose position is shaped or pressure-advanced (linear kinematics), and every plug-in motor (an
inverse-kinematics function as the search's position callback, as Klipper's calc_position), take Klipper's own
search instead (:func:`kernel.itersolve_steps`, docs/design.md §11): its trapq (:class:`_Trapq`) and
step-generation windows decide where the search restarts, and it skips the excursions Klipper's probes miss.
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
# Klipper generates steps in windows of 0.25 s of print time (motion_queuing.py: BGFLUSH_SG_HIGH_TIME −
# BGFLUSH_SG_LOW_TIME), counted from print time 0, and starts the first move at print time 0.25 s
# (toolhead.py BUFFER_TIME_START): window ends at t = −0.25 + k·0.25 s from the first move's start
KLIPPER_FLUSH_STEP_T = 0.25
KLIPPER_FIRST_MOVE_T = 0.25
KLIPPER_KINEMATIC_MIN_MM = 1e-9     # toolhead.py: shorter XYZ moves are extrude-only (not in the XY trapq)
# per-row motion bits for the trapq model: which axes the row's move displaces, and which queue it enters
BIT_X, BIT_Y, BIT_Z, BIT_E, BIT_KIN = 1, 2, 4, 8, 16
TRAPQ_KEEP_S = 2.0        # s of trapq history kept for motors whose search has not started (≫ any shaper reach)

Sink = Callable[[int, np.ndarray, np.ndarray], None]


def _unreachable(rail, t_s) -> ConfigError:
    """The error for a plug-in motor whose inverse kinematics gives no position at time ``t_s`` (s)."""
    return ConfigError(f"{rail.name}: the kinematics cannot reach the position at t = {float(t_s)!r} s "
                       f"(its inverse kinematics gives no motor position there)")


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
    extruder motors without pressure advance see the planner's pieces untouched. A linear motor while
    shaped or smoothed, and a plug-in motor (its ``ik``) always, is stepped by Klipper's own search
    (:class:`_Itersolve`), which applies the step+dir+step filter the way Klipper's stepcompress does (when
    ``sds_filter_t`` is set).
    """

    #: the plug-in motors' step searches (``ik_search``): "klipper" — Klipper's own search with the ik as its callback
    #: (:meth:`_run_ik_klipper`, steps within ~10 ns of Klipper's on every reference file, the default); "exact" —
    #: the step engine's guarded search (:func:`kernel.gen_steps_ik`, about 2x faster, each step within 1 ns of
    #: its half-step point), which differs from Klipper's by up to ~1.3 µs on rotary motors (rad) at low angular
    #: speed, where Klipper's search stops within 1e-9 rad of the point (1e-9 rad / 0.0008 rad/s = 1.2 µs); "fit" — the
    #: step engine on verified polynomial stand-ins of the ik along each piece (:func:`kernel.ik_fit_pieces`: no ik
    #: call per step; each step within ``ik_fit_tol_s`` of the exact search's where the motor moves, the exact search
    #: itself where no stand-in verifies, as near turning points)
    IK_SEARCHES = ("klipper", "exact", "fit")


    def __init__(self, rails: list[Rail], sink: Sink, *, chunk_steps: int = DEFAULT_CHUNK_STEPS,
                 sds_filter_t: float | None = None, settings: np.ndarray | None = None,
                 flush_times: np.ndarray | None = None, ik_search: str = "klipper"):
        """``flush_times``: the ends (s from the first move's start, increasing) of Klipper's step-generation
        windows, where its search restarts (shaped and pressure-advanced motors, plug-in kinematics; see
        :class:`_Itersolve`). Default: every 0.25 s, as Klipper batches while the printer keeps up (a printer's
        windows follow its host's timing, so no other default is more right). Klipper's batch mode
        (``klippy.py -i -o``, how its reference step files are made) skips some where a 4096-byte read holds
        more than ~25 s of motion: :func:`gcodeplan.stepper.klipper_batch.klipper_batch_flush_times` gives its
        windows (``gcodeplan steps --klipper-batch``). ``ik_search``: how plug-in motors are stepped
        (IK_SEARCHES)."""
        if ik_search not in self.IK_SEARCHES:
            from ..errors import ConfigError

            raise ConfigError(f"ik_search: {ik_search!r} is not one of {', '.join(self.IK_SEARCHES)}")
        self.ik_klipper_search = ik_search == "klipper"   # plug-in motors: Klipper's search, else the exact one
        self.ik_fit = ik_search == "fit"                   # ... on verified polynomial stand-ins where they verify
        self.ik_fit_tol_s = kernel.IK_FIT_TOL_S            # s, the stand-ins' step-time bound (kernel section comment)
        self.ik_fit_round = kernel.IK_FIT_ROUND            # their rounding floor (negative: none; tests force fallback)
        self.rails = list(rails)
        self.flush_times = None if flush_times is None else np.asarray(flush_times, np.float64)
        self.sink = sink
        self.sds_filter_t = sds_filter_t
        n = len(self.rails)
        self.states = [kernel.new_state() for _ in range(n)]
        self.stats = [kernel.new_stats() for _ in range(n)]
        self._sds = [np.zeros(kernel.SDS_STATE_LEN) for _ in range(n)]
        self._buf_t = [np.empty(chunk_steps, np.float64) for _ in range(n)]
        self._buf_d = [np.empty(chunk_steps, np.int8) for _ in range(n)]
        self._fill = [0] * n
        self._last_t = [-np.inf] * n      # s, the last step time handed out per stepper (kernel.monotone_stats)
        self.steps_generated = 0      # before the filter
        self.settings = None if settings is None else np.asarray(settings).reshape(-1)[:1]
        # which motors shaping and pressure advance act on (a delta tower moves with X and Y)
        self._xy_rails = [i for i, r in enumerate(self.rails)
                          if r.tower is not None or r.ik is not None
                          or (r.weights is not None and (r.weights[0] or r.weights[1]))]
        # a plug-in motor's compiled inverse kinematics and its parameters: the position callback of Klipper's
        # search (kernel.itersolve_steps), which steps every plug-in motor
        self._ik_params = [None if r.ik is None else np.ascontiguousarray(r.ik_params or (0.0,), np.float64)
                           for r in self.rails]
        self._ik_fn = [None] * n      # the cfunc of each, made on first use (kinematics.plugin.ik_cfunc)
        self._ik_bound = [None] * n   # the same with its parameters bound (kinematics.plugin.ik_bound_cfunc)
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
        # Klipper's own search on the shaped / pressure-advanced linear motors and on every plug-in motor (delta
        # towers keep the exact kernel): one trapq per motion queue, one search state per motor
        self._ik_rails = [i for i, r in enumerate(self.rails) if r.ik is not None]
        self._trapq_xy = _Trapq(BIT_KIN, lambda bits: bits,
                                sum(self.rails[i].tower is None for i in self._xy_rails))
        self._trapq_e = _Trapq(BIT_E, lambda bits: np.where(bits & BIT_E, BIT_E, 0), len(self._e_rails))
        self._its: dict[int, _Itersolve] = {}
        self._its_mode = [False] * n         # rail currently stepped by the search (else the exact kernels)

    # ---------------------------------------------------------------- settings per piece
    def _piece_settings(self, segments, moves, limits, first_move):
        """(shaper key index per piece, keys, K per piece (0 where Klipper does not advance), h per piece)."""
        n = len(segments)
        if moves is not None and limits is not None and len(moves):
            idx = segments["move"].astype(np.int64)
            if idx.min() >= first_move and idx.max() < first_move + len(moves):
                idx = idx - first_move
            idx = np.clip(idx, 0, len(moves) - 1)
            # per move first, then per row: gathering whole MOVE / LIMITS records row by row costs more than
            # the rest of the settings together
            can_pa = (((moves["x1"] != moves["x0"]) | (moves["y1"] != moves["y0"])) & (moves["e1"] > moves["e0"]))[idx]
            lim = _LimitColumns(np.asarray(limits), moves["limits"].astype(np.int64)[idx])
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
            if self._ik_rails and self.ik_klipper_search:
                self._trapq_xy.add(segments["t0"], segments["dt"], _row_bits(segments, moves, first_move))
            for si, rail in enumerate(self.rails):
                if rail.tower is not None or rail.ik is not None:
                    cols = cols or _xyz_columns(segments)
                    (self._run_delta if rail.ik is None else self._run_ik)(si, *cols, reset)
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
        bits = _row_bits(segments, moves, first_move)
        # shaping and smoothing cost a little per call: gather small batches (the planner emits one per
        # full stop) into big ones
        self._pending.append((segments, reset) + tuple(st) + (bits,))
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
        reset, raw, k_pa, h, bits = (np.concatenate([p[i] for p in parts]) for i in range(1, 6))
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
            self._trapq_xy.add(segments["t0"], segments["dt"], bits)
            self._feed_shaped(segments, reset, key_idx, keys)
        if self._e_rails:
            if self._mixed_e and np.any(k_pa != 0):
                raise ConfigError(f"pressure advance on a motor that also moves with X/Y/Z "
                                  f"({', '.join(self._mixed_e)}) is not modelled")
            self._trapq_e.add(segments["t0"], segments["dt"], bits)
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
            self._step_group(cur, self._xy_rails, out, horizon=cur.stream.end_u)

    def _step_group(self, cur, rails, out, horizon=None):
        """Step the pieces ``out`` (shaped Pieces or SEGMENT rows) on ``rails``. A linear motor that the current
        stream shapes runs Klipper's own search up to ``horizon`` (s, where the pieces known so far end; None:
        the pieces' end); the others, and delta towers, the exact kernels."""
        flag = cur.flag
        if len(out) == 0:
            if horizon is not None:
                for si in rails:
                    if self._its_mode[si]:
                        self._run_its(si, horizon)
            return
        rs = np.zeros(len(out), np.uint8)
        if cur.flag:
            rs[0] = cur.flag
            cur.flag = 0
        cols = None
        for si in rails:
            rail = self.rails[si]
            if rail.tower is not None or rail.ik is not None:
                # delta, plug-ins: the shaped x, y (and z) pieces through the motor's own kernel
                if cols is None:
                    cols = _xyz_columns(out) if isinstance(out, np.ndarray) else (out.t0, out.dt, out.p, out.v,
                                                                                  out.a, out.j)
                if rail.ik is None:
                    self._run_delta(si, *cols, rs)
                else:
                    self._run_ik(si, *cols, rs, reach=_reach(cur.stream, rail, False), horizon=horizon)
                continue
            reach = _reach(cur.stream, rail, si in self._e_rails)
            if reach != (0.0, 0.0) and not isinstance(out, np.ndarray):
                # shaped pieces straight into the search's coefficient rows (no per-column sums and copies)
                coef = np.empty((len(out), kernel.POLY_NCOEF))
                kernel.linear_poly(out.p, out.v, out.a, out.j, np.asarray(rail.weights, np.float64), coef)
                its = self._enter_its(si, reach, float(out.t0[0]), flag)
                its.add_coef(out.t0, out.dt, coef)
                self._run_its(si, float(out.t0[-1] + out.dt[-1]) if horizon is None else horizon)
                continue
            if isinstance(out, np.ndarray):
                t0, dt, p, v, a, j = stepper_pieces(out, rail)
            else:
                t0, dt, p, v, a, j = out.rail(rail.weights)
            if reach == (0.0, 0.0):
                # not shaped: Klipper's search finds exactly the crossings of these monotone phases
                self._leave_its(si)
                self._run(si, t0, dt, p, v, a, j, rs)
                continue
            its = self._enter_its(si, reach, float(t0[0]), flag)
            its.add_pieces(t0, dt, p, v, a, j)
            self._run_its(si, float(t0[-1] + dt[-1]) if horizon is None else horizon)

    # ---------------------------------------------------------------- Klipper's search (itersolve)
    def _enter_its(self, si, reach, t_from, flag) -> "_Itersolve":
        """Rail ``si``'s search, its reach (pre, post) s set. On entry from the exact kernel the commanded
        position and the last direction carry over; a position set at ``t_from`` restarts it there."""
        its = self._its.get(si)
        rail = self.rails[si]
        if its is None:
            trapq = self._trapq_e if si in self._e_rails else self._trapq_xy
            if rail.ik is not None:
                # a plug-in motor may move with any of X, Y, Z (Klipper's rotary delta, winch: AF_X | AF_Y | AF_Z;
                # a move that leaves it still gives no step either way)
                mask = BIT_X | BIT_Y | BIT_Z
            elif si in self._e_rails:
                mask = BIT_E
            else:
                mask = BIT_X * (rail.weights[0] != 0) | BIT_Y * (rail.weights[1] != 0) | BIT_Z * (rail.weights[2] != 0)
            its = self._its[si] = _Itersolve(trapq, int(mask), rail.step_dist, self.sds_filter_t or 0.0,
                                             self.flush_times)
            if rail.ik is not None:
                its.set_ik(self._ik_callback(si), self._ik_params[si], rail.period)
        if flag == kernel.RESET_ANCHOR and self._its_mode[si]:
            self._close_its(si, t_from)
            its.restart(t_from)
        if not self._its_mode[si]:
            # the exact steps so far leave through their own filter; the search takes over from t_from
            self._flush(si)
            if self.sds_filter_t is not None:
                t, d = kernel.sds_flush(self._sds[si])
                self._emit(si, t, d)
            ex = self.states[si]
            anchored = ex[kernel.S_ANCHORED] != 0.0 and flag != kernel.RESET_ANCHOR
            its.resume(t_from, ex[kernel.S_ANCHOR] + ex[kernel.S_N] * rail.step_dist if anchored else None,
                       self.stats[si][3] > 0)
            self._its_mode[si] = True
        its.pre_t, its.post_t = reach
        return its

    def _leave_its(self, si) -> None:
        """Back to the exact kernel (shaping or smoothing switched off): it goes on from the commanded position."""
        if not self._its_mode[si]:
            return
        its = self._its[si]
        self._flush(si)
        t, d = kernel.itersolve_flush_pending(its.state)
        self._emit(si, t, d)
        ex = self.states[si]
        ex[kernel.S_ANCHOR] = its.state[kernel.I_COMMANDED]
        ex[kernel.S_N] = 0.0
        ex[kernel.S_LAST_POS] = its.end_position()
        ex[kernel.S_ANCHORED] = 1.0
        self._its_mode[si] = False
        its.running = False

    def _run_its(self, si, horizon):
        its = self._its[si]
        while True:
            done, fill = its.run(horizon, self._buf_t[si], self._buf_d[si], self._fill[si])
            self.steps_generated += fill - self._fill[si]
            self._fill[si] = fill
            if done:
                return
            if fill == 0:        # one window holds more steps than the buffer: grow it
                self._buf_t[si] = np.empty(2 * len(self._buf_t[si]), np.float64)
                self._buf_d[si] = np.empty(2 * len(self._buf_d[si]), np.int8)
            else:
                self._flush(si)

    def _close_its(self, si, end_t):
        """Klipper flushes all steps when the position is set or a shaper / smoothing changes: a window
        ends at ``end_t``."""
        if self._its_mode[si]:
            self._its[si].force_flush(end_t)
            self._run_its(si, end_t)

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
                self._step_group(cur, self._e_rails, part,
                                 horizon=float(part["t0"][-1] + part["dt"][-1]) if len(part) else None)
                if len(part):
                    cur.end_u = float(part["t0"][-1] + part["dt"][-1])
                continue
            t0, dt, c = cur.stream.feed(part["t0"], part["dt"], part["pe"], part["ve"], part["ae"], part["je"],
                                        k_pa[i0:i1])
            self._step_poly(cur, t0, dt, c)

    def _step_poly(self, cur, t0, dt, c):
        if len(t0) == 0:
            for si in self._e_rails:
                if self._its_mode[si] and cur.stream is not None:
                    self._run_its(si, cur.stream.end_u)
            return
        flag = cur.flag
        cur.flag = 0
        for si in self._e_rails:
            w = self.rails[si].weights[3]
            coef = c if w == 1.0 else c * w
            its = self._enter_its(si, _reach(cur.stream, self.rails[si], True), float(t0[0]), flag)
            its.add_coef(t0, dt, np.ascontiguousarray(coef))
            self._run_its(si, float(t0[-1] + dt[-1]))
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
        if np.isfinite(cur.end_u):
            for si in rails:
                self._close_its(si, cur.end_u)
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

    def _ik_callback(self, si):
        """Plug-in motor ``si``'s compiled inverse kinematics (made on first use)."""
        if self._ik_fn[si] is None:
            from ..kinematics.plugin import ik_cfunc

            self._ik_fn[si] = ik_cfunc(self.rails[si].ik)
        return self._ik_fn[si]

    def _run_ik(self, si, t0, dt, p, v, a, j, reset, reach=(0.0, 0.0), horizon=None):
        """Steps of plug-in motor ``si`` from pieces with (n, ≥3) x, y, z coefficient columns: Klipper's search
        (:meth:`_run_ik_klipper`) or, with ``ik_klipper_search`` False, the step engine with the guarded root
        search on the motor's inverse kinematics (:func:`kernel.gen_steps_ik`), as the delta towers run theirs.
        ``reach``/``horizon`` serve Klipper's search only: the guarded search steps shaped pieces as they come."""
        if self.ik_klipper_search:
            self._run_ik_klipper(si, t0, dt, p, v, a, j, reset, reach, horizon)
            return
        n_pieces = len(t0)
        if n_pieces == 0:
            return
        rail = self.rails[si]
        fn = self._ik_bound[si]
        if fn is None:
            from ..kinematics.plugin import ik_bound_cfunc

            fn = self._ik_bound[si] = ik_bound_cfunc(rail.ik, self._ik_params[si])
        period = float(rail.period or 0.0)
        start = 0
        refs = kernel.ik_branch_refs(t0, dt, p, v, a, j, fn, period, self.states[si], start)
        if self.ik_fit:
            self._run_ik_fit(si, t0, dt, p, v, a, j, reset, fn, period, refs)
            return
        while start < n_pieces:
            nxt, fill, need = kernel.gen_steps_ik(t0, dt, p, v, a, j, reset, fn, period, refs,
                                                  rail.step_dist, self.states[si], start, self._buf_t[si],
                                                  self._buf_d[si], self._fill[si])
            if need == kernel.PIECE_UNREACHABLE:
                raise _unreachable(rail, t0[nxt])
            start = self._after_kernel(si, t0, nxt, fill, need, n_pieces)

    def _run_ik_fit(self, si, t0, dt, p, v, a, j, reset, fn, period, refs):
        """Steps of plug-in motor ``si`` on verified polynomial stand-ins of its ik (:func:`kernel.ik_fit_pieces`),
        the exact search where none verifies (:func:`kernel.gen_steps_ik_fit`)."""
        rail = self.rails[si]
        ft0, fdt, coef, mode, src, freset = kernel.ik_fit_pieces(t0, dt, p, v, a, j, reset, fn, period, refs,
                                                                 self.ik_fit_tol_s, self.ik_fit_round)
        start = 0
        n_fit = len(ft0)
        if n_fit and np.all(mode == kernel.FIT_CUBIC):
            # every stand-in a cubic (a linear ik): the linear kernel itself, on the same (p, v, a, j) the fit
            # kernel hands its functions (the same steps, without the per-step choice of mode)
            p1 = np.ascontiguousarray(coef[:, 0])
            v1 = np.ascontiguousarray(coef[:, 1])
            a1 = 2.0 * coef[:, 2]
            j1 = 6.0 * coef[:, 3]
            while start < n_fit:
                nxt, fill, need = kernel.gen_steps(ft0, fdt, p1, v1, a1, j1, freset, rail.step_dist, self.states[si],
                                                   start, self._buf_t[si], self._buf_d[si], self._fill[si])
                start = self._after_kernel(si, ft0, nxt, fill, need, n_fit)
            return
        while start < n_fit:
            nxt, fill, need = kernel.gen_steps_ik_fit(ft0, fdt, coef, mode, src, freset, p, v, a, j, fn, period, refs,
                                                      t0, dt, rail.step_dist, self.states[si], start,
                                                      self._buf_t[si], self._buf_d[si], self._fill[si])
            if need == kernel.PIECE_UNREACHABLE:
                raise _unreachable(rail, ft0[nxt])
            start = self._after_kernel(si, ft0, nxt, fill, need, n_fit)

    def _run_ik_klipper(self, si, t0, dt, p, v, a, j, reset, reach=(0.0, 0.0), horizon=None):
        """Steps of plug-in motor ``si`` from pieces with (n, ≥3) x, y, z coefficient columns: Klipper's search
        (:func:`kernel.itersolve_steps`) with the motor's inverse kinematics as its position callback, as
        Klipper's itersolve.c takes each kinematics' calc_position. ``reach``: the shaper's (pre, post) s;
        ``horizon``: where the pieces known so far end (None: the pieces' end). A position set at a row
        (RESET_ANCHOR) ends a step-generation window there and restarts the search (itersolve_set_position)."""
        n_pieces = len(t0)
        if n_pieces == 0:
            if horizon is not None and self._its_mode[si]:
                self._run_its(si, horizon)
            return
        finite = np.isfinite(dt)
        for col in (p, v, a, j):
            finite &= np.isfinite(col[:, :3]).all(axis=1)
        if not finite.all():
            bad = int(np.flatnonzero(~finite)[0])
            raise RuntimeError(f"{self.rails[si].name}: plan piece at t = {float(t0[bad])!r} s has a non-finite "
                               f"coefficient (a planner bug)")
        fn = self._ik_callback(si)
        rail = self.rails[si]
        coef = np.empty((n_pieces, kernel.IK_NCOEF))
        for q in range(3):
            coef[:, 4 * q] = p[:, q]
            coef[:, 4 * q + 1] = v[:, q]
            coef[:, 4 * q + 2] = 0.5 * a[:, q]
            coef[:, 4 * q + 3] = j[:, q] * (1.0 / 6.0)
        # every motor position the search may ask for must exist (a NaN would pass for a step): the function at
        # IK_CHECK_SAMPLES + 1 points of each piece, as the earlier sampling engine checked it
        s = dt[:, None] * np.linspace(0.0, 1.0, kernel.IK_CHECK_SAMPLES + 1)[None, :]
        xyz = [coef[:, 4 * q, None] + s * (coef[:, 4 * q + 1, None] + s * (coef[:, 4 * q + 2, None]
                                                                          + s * coef[:, 4 * q + 3, None]))
               for q in range(3)]
        pos = kernel.ik_positions(fn, self._ik_params[si], xyz[0].ravel(), xyz[1].ravel(), xyz[2].ravel())
        if not np.all(np.isfinite(pos)):
            k = int(np.flatnonzero(~np.isfinite(pos))[0]) // (kernel.IK_CHECK_SAMPLES + 1)
            raise _unreachable(rail, t0[k])
        cuts = [0] + (np.flatnonzero(reset[1:] == kernel.RESET_ANCHOR) + 1).tolist() + [n_pieces]
        for i0, i1 in zip(cuts[:-1], cuts[1:]):
            its = self._enter_its(si, reach, float(t0[i0]), int(reset[i0]))
            its.add_coef(t0[i0:i1], dt[i0:i1], coef[i0:i1])
            end = float(t0[i1 - 1] + dt[i1 - 1])
            self._run_its(si, end if horizon is None or i1 < n_pieces else horizon)

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
        if self.sds_filter_t is not None and not self._its_mode[si]:    # Klipper's search filters as it goes
            out_t = np.empty(fill, np.float64)
            out_d = np.empty(fill, np.int8)
            m = kernel.sds_filter(times, dirs, self.sds_filter_t, self._sds[si], out_t, out_d)
            times, dirs = out_t[:m], out_d[:m]
        self._emit(si, times, dirs)
        self._fill[si] = 0

    def feed_pulses(self, si: int, times: np.ndarray, dirs: np.ndarray) -> None:
        """Step pulses made elsewhere (a firmware model's stepper interrupt) for stepper ``si``, in time order
        after everything fed before: counted and handed to the sink as they are."""
        self._flush(si)
        self._emit(si, np.ascontiguousarray(times, np.float64), np.ascontiguousarray(dirs, np.int8))

    def _emit(self, si: int, times: np.ndarray, dirs: np.ndarray) -> None:
        if len(times):
            self._last_t[si] = kernel.monotone_stats(times, dirs, self._last_t[si], self.stats[si])
            self.sink(si, times, dirs)

    def release(self) -> None:
        """Hand every step computed so far to the sink now (as a full buffer would be), without closing the
        streams: gcodeplan.Toolhead.steps() gives the steps of the final moves as they come."""
        for si in range(len(self.rails)):
            self._flush(si)

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
            its = self._its.get(si) if self._its_mode[si] else None
            if its is not None:
                its.force_flush(np.inf)
                self._run_its(si, np.inf)
            self._flush(si)
            if its is not None:
                t, d = kernel.itersolve_flush_pending(its.state)
                self._emit(si, t, d)
            elif self.sds_filter_t is not None:
                t, d = kernel.sds_flush(self._sds[si])
                self._emit(si, t, d)


class _LimitColumns:
    """The LIMITS columns of rows ``limits[index]``, gathered column by column on first use."""

    def __init__(self, limits: np.ndarray, index: np.ndarray):
        self.limits = limits
        self.index = index
        self.cache: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        col = self.cache.get(name)
        if col is None:
            col = self.cache[name] = self.limits[name][self.index]
        return col


class _StreamState:
    """One group of motors' current stream (shaped or smoothed) and where its output ends."""

    def __init__(self):
        self.stream = None
        self.key = None
        self.started = False
        self.flag = 0
        self.end_u = -np.inf


_SHAPER_NAMES = SHAPER_TYPES


def _row_bits(segments: np.ndarray, moves: np.ndarray | None, first_move: int) -> np.ndarray:
    """Per SEGMENT row, BIT_* of its move: the axes it displaces (Klipper's axes_r != 0, hence check_active)
    and BIT_KIN when it enters the XY trapq (toolhead.py: XYZ length ≥ 1e-9 mm). From the MOVE rows when
    given, else from the row's own coefficients."""
    n = len(segments)
    bits = np.zeros(n, np.int64)
    if moves is not None and len(moves):
        idx = segments["move"].astype(np.int64)
        if idx.min() >= first_move and idx.max() < first_move + len(moves):
            idx = idx - first_move
        # the bits of each move, then of each row (cheaper than gathering whole MOVE records per row)
        mb = np.zeros(len(moves), np.int64)
        d = [moves[ax + "1"] - moves[ax + "0"] for ax in "xyz"]
        for b, di in zip((BIT_X, BIT_Y, BIT_Z), d):
            mb |= np.where(di != 0, b, 0)
        mb |= np.where(moves["e1"] != moves["e0"], BIT_E, 0)
        kin = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) >= KLIPPER_KINEMATIC_MIN_MM
        mb |= np.where(kin, BIT_KIN, 0)
        return mb[np.clip(idx, 0, len(moves) - 1)]
    else:
        for b, ax in zip((BIT_X, BIT_Y, BIT_Z, BIT_E), "xyze"):
            moving = (segments["v" + ax] != 0) | (segments["a" + ax] != 0) | (segments["j" + ax] != 0)
            bits |= np.where(moving, b, 0)
        kin = (bits & (BIT_X | BIT_Y | BIT_Z)) != 0
    bits |= np.where(kin, BIT_KIN, 0)
    return bits


def _reach(stream, rail: Rail, is_e: bool) -> tuple[float, float]:
    """(pre, post) s: how long before / after its active moves Klipper steps this motor (kin_shaper.c
    shaper_note_generation_time: the latest and earliest pulse of the axes it follows; kin_extruder.c: the
    half smooth time)."""
    if stream is None:
        return 0.0, 0.0
    if is_e:
        return float(stream.h), float(stream.h)
    pre = post = 0.0
    for q in (0, 1):
        if rail.weights is not None and rail.weights[q] == 0.0:
            continue
        sel = (stream.ch_axis == q) & (stream.ch_tau != 0.0)
        if np.any(sel):
            pre = max(pre, float(stream.ch_tau[sel].max()))
            post = max(post, float(-stream.ch_tau[sel].min()))
    return pre, post


class _Trapq:
    """One of Klipper's motion queues as its itersolve walks it (trapq.c): the planner's phases of the moves that
    enter it (``enter_bit`` in their row bits), the gaps between them as null moves, and before the first one the
    head sentinel and a null move from print time 0 (t = −0.25 s). ``axes_of(bits)`` gives the bits the
    motors' active masks test. Moves are kept from ``base`` (global index of ``start[0]``) on."""

    def __init__(self, enter_bit: int, axes_of, n_users: int):
        self.enter_bit = enter_bit
        self.n_users = n_users          # motors that will read this queue (moves are kept until all have passed)
        self.axes_of = axes_of
        self.start = np.array([-KLIPPER_FIRST_MOVE_T])
        self.length = np.zeros(1)
        self.bits = np.zeros(1, np.int64)
        self.end = -KLIPPER_FIRST_MOVE_T
        self.base = 0
        self.users: list[_Itersolve] = []        # the searches reading this queue (``running`` while they do)
        self.keep_t = self.end

    def add(self, t0, dt, bits) -> None:
        """Append SEGMENT rows (time order): those entering the queue with a non-zero duration become moves."""
        # a search that starts later starts within this batch: nothing before the previous batch's end matters
        self.keep_t = self.end
        sel = np.flatnonzero(((bits & self.enter_bit) != 0) & (dt > 0))
        if len(sel) == 0:
            return
        s = np.asarray(t0[sel], np.float64)
        ln = np.asarray(dt[sel], np.float64)
        b = np.asarray(self.axes_of(bits[sel]), np.int64)
        e = s + ln
        prev_end = np.concatenate(([self.end], e[:-1]))
        gap = s > prev_end
        m = len(sel) + int(gap.sum())
        start = np.empty(m)
        length = np.empty(m)
        mb = np.zeros(m, np.int64)
        pos = np.arange(len(sel)) + np.cumsum(gap)
        start[pos] = s
        length[pos] = ln
        mb[pos] = b
        gpos = pos[gap] - 1
        start[gpos] = prev_end[gap]
        length[gpos] = s[gap] - prev_end[gap]
        self.start = np.concatenate((self.start, start))
        self.length = np.concatenate((self.length, length))
        self.bits = np.concatenate((self.bits, mb))
        self.end = float(e[-1])
        self.trim()

    def index_after(self, t: float) -> int:
        """Global index of the first move ending after ``t``."""
        return self.base + int(np.searchsorted(self.start + self.length, t, side="right"))

    def trim(self) -> None:
        """Drop the moves every running search has passed; a search that is not running starts from the recent
        past only (:meth:`_Itersolve.resume`)."""
        running = [u.move_base for u in self.users if u.running]
        keep = min(running) if running else None
        if keep is None or len(running) < self.n_users:
            recent = self.index_after(self.keep_t - TRAPQ_KEEP_S)
            keep = recent if keep is None else min(keep, recent)
        k = keep - self.base
        if k > 4096:
            self.start, self.length, self.bits = self.start[k:], self.length[k:], self.bits[k:]
            self.base += k


class _Itersolve:
    """One motor under Klipper's own search (:func:`kernel.itersolve_steps`): its pieces (degree ≤ 5, power
    basis) as they stream in, its place in the trapq, its step-generation windows and search state."""

    def __init__(self, trapq: _Trapq, mask: int, step_dist: float, sds_t: float, flush_times):
        self.trapq = trapq
        trapq.users.append(self)
        self.mask = mask
        self.step_dist = step_dist
        self.sds_t = sds_t
        self.flush_times = flush_times
        self.next_flush = 0                   # index into flush_times, or k of the regular windows
        self.forced: list[float] = []
        self.state = kernel.new_itersolve_state()
        self.move_base = trapq.base           # global trapq index of the state's move 0
        self.running = False                  # stepping its motor now (else the exact kernel does)
        self.pt0 = np.zeros(0)
        self.pdt = np.zeros(0)
        self.coef = np.zeros((0, kernel.POLY_NCOEF))
        self.pre_t = 0.0
        self.post_t = 0.0
        self.ik = None              # a plug-in motor's position callback (set_ik)
        self.ik_params = None
        self.period = 0.0

    def set_ik(self, ik, params, period) -> None:
        """Position from a plug-in's inverse kinematics ``ik`` (cfunc) of x, y, z pieces (kernel.IK_NCOEF columns)
        instead of polynomial pieces."""
        self.ik = ik
        self.ik_params = params
        self.period = float(period or 0.0)
        self.coef = np.zeros((0, kernel.IK_NCOEF))

    def add_pieces(self, t0, dt, p, v, a, j) -> None:
        c = np.zeros((len(t0), kernel.POLY_NCOEF))
        c[:, 0] = p
        c[:, 1] = v
        c[:, 2] = 0.5 * a
        c[:, 3] = j * (1.0 / 6.0)
        self.add_coef(t0, dt, c)

    def add_coef(self, t0, dt, c) -> None:
        # the pieces the search has passed are dropped first (it never looks back past its last window)
        lft = self.state[kernel.I_LAST_FLUSH]
        k = int(np.searchsorted(self.pt0 + self.pdt, lft, side="left")) if len(self.pt0) else 0
        k = min(k, max(len(self.pt0) - 1, 0), int(self.state[kernel.I_PIECE]))
        if k == len(self.pt0):
            self.pt0, self.pdt, self.coef = np.asarray(t0, np.float64), np.asarray(dt, np.float64), c
        else:
            self.pt0 = np.concatenate((self.pt0[k:], np.asarray(t0, np.float64)))
            self.pdt = np.concatenate((self.pdt[k:], np.asarray(dt, np.float64)))
            self.coef = np.concatenate((self.coef[k:], c))
        self.state[kernel.I_PIECE] -= k

    def resume(self, t: float, commanded: float | None, forward: bool) -> None:
        """Take over at ``t`` from the exact kernel: its commanded position (None: read it at t) and the
        direction of its last step; windows and pieces before t are done."""
        st = self.state
        st[kernel.I_STARTED] = 0.0 if commanded is None else 1.0
        st[kernel.I_COMMANDED] = 0.0 if commanded is None else commanded
        st[kernel.I_START_T] = t
        st[kernel.I_DIR] = 1.0 if forward else 0.0
        st[kernel.I_PENDING] = 0.0
        # nothing before t is stepped (again)
        st[kernel.I_LAST_FLUSH] = t
        st[kernel.I_LAST_MOVE] = -np.inf
        self.forced = []
        if self.flush_times is not None:
            self.next_flush = int(np.searchsorted(self.flush_times, t, side="right"))
        else:
            self.next_flush = max(int(np.floor((t + KLIPPER_FIRST_MOVE_T) / KLIPPER_FLUSH_STEP_T + 1e-9)) + 1, 0)
        self.pt0 = np.zeros(0)
        self.pdt = np.zeros(0)
        self.coef = np.zeros((0, self.coef.shape[1]))
        st[kernel.I_PIECE] = 0.0
        st[kernel.I_MOVE] = 0.0
        self.move_base = max(self.move_base, min(self.trapq.index_after(t - TRAPQ_KEEP_S),
                                                 self.trapq.base + len(self.trapq.start) - 1))
        self.running = True

    def end_position(self) -> float:
        """The position (mm) at the end of the pieces received (polynomial pieces)."""
        c = self.coef[-1]
        s = self.pdt[-1]
        return float(c[0] + s * (c[1] + s * (c[2] + s * (c[3] + s * (c[4] + s * c[5])))))

    def restart(self, t: float) -> None:
        """The position was set at ``t`` (G28 / SET_KINEMATIC_POSITION): the commanded position is the position
        there (Klipper's itersolve_set_position)."""
        self.state[kernel.I_STARTED] = 0.0
        self.state[kernel.I_START_T] = t

    def force_flush(self, t: float) -> None:
        """A window ends at ``t`` (Klipper's flush_step_generation)."""
        self.forced.append(t)

    def _windows(self, horizon: float) -> np.ndarray:
        """The window ends not yet processed, up to ``horizon`` (the forced ones merged in)."""
        last = self.state[kernel.I_LAST_FLUSH]
        if self.flush_times is not None:
            ft = self.flush_times
            k = self.next_flush
            hi = int(np.searchsorted(ft, horizon, side="right"))
            reg = ft[k:hi]
        else:
            k0 = max(self.next_flush, 0)
            top = horizon if np.isfinite(horizon) else (self.pt0[-1] + self.pdt[-1] + 1.0 if len(self.pt0) else last)
            k1 = int(np.floor((top + KLIPPER_FIRST_MOVE_T) / KLIPPER_FLUSH_STEP_T)) + 1
            reg = -KLIPPER_FIRST_MOVE_T + KLIPPER_FLUSH_STEP_T * np.arange(k0, max(k1, k0), dtype=np.float64)
            reg = reg[reg <= horizon]
        forced = [f for f in self.forced if f <= horizon]
        w = np.concatenate((reg, np.array(forced, np.float64))) if forced else reg
        if forced:
            w = np.unique(w)
        return w[w > last]

    def run(self, horizon: float, out_t, out_dir, out_n) -> tuple[bool, int]:
        """Process the windows ending up to ``horizon``; (all done, new out_n) — not all done means ``out_t`` is
        full (empty it and call again)."""
        if len(self.pt0) == 0:
            return True, out_n
        w = self._windows(horizon)
        if len(w) == 0:
            return True, out_n
        tq = self.trapq
        k0 = self.move_base - tq.base
        m_start = np.concatenate((tq.start[k0:], [tq.end]))
        m_len = np.concatenate((tq.length[k0:], [kernel.ITS_NEVER_S]))
        m_act = np.concatenate(((tq.bits[k0:] & self.mask) != 0, [False]))
        if self.ik is None:
            done, out_n = kernel.itersolve_steps(w, m_start, m_len, m_act, self.pre_t, self.post_t, self.pt0,
                                                 self.pdt, self.coef, self.step_dist, self.sds_t, self.state, out_t,
                                                 out_dir, out_n)
        else:
            done, out_n = kernel.itersolve_steps(w, m_start, m_len, m_act, self.pre_t, self.post_t, self.pt0,
                                                 self.pdt, self.coef, self.step_dist, self.sds_t, self.state, out_t,
                                                 out_dir, out_n, self.ik, self.ik_params, self.period)
        if done:
            last = w[done - 1]
            if self.flush_times is not None:
                self.next_flush = int(np.searchsorted(self.flush_times, last, side="right"))
            elif np.isfinite(last):
                self.next_flush = int(np.floor((last + KLIPPER_FIRST_MOVE_T) / KLIPPER_FLUSH_STEP_T + 1e-9)) + 1
            self.forced = [f for f in self.forced if f > last]
            self._trim()
        return done == len(w), out_n

    def _trim(self) -> None:
        st = self.state
        mi = int(st[kernel.I_MOVE])
        if mi > 0:
            self.move_base += mi
            st[kernel.I_MOVE] = 0
        self.trapq.trim()
        lft = st[kernel.I_LAST_FLUSH]
        ends = self.pt0 + self.pdt
        k = min(int(np.searchsorted(ends, lft, side="left")), len(self.pt0) - 1)
        if k > 1024:
            self.pt0, self.pdt, self.coef = self.pt0[k:], self.pdt[k:], self.coef[k:]
            st[kernel.I_PIECE] = max(st[kernel.I_PIECE] - k, 0.0)


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
                   reset: np.ndarray | None = None, settings: np.ndarray | None = None,
                   flush_times: np.ndarray | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """All step times in memory: {stepper name: (times s, dirs int8)}. For tests and small files.

    ``segments`` is one SEGMENT array or an iterable of batches (``reset`` only
    applies to a single array). Steppers come from ``rails``, else from ``kinematics``
    (a built-in name or an object with ``rails(machine, klipper_names)``, e.g.
    :class:`gcodeplan.kinematics.Linear`), else from the machine. ``settings``: the
    LIMITS row whose input-shaper / pressure-advance columns apply (default: the
    machine's, ``machine.limits_row()``). ``flush_times``: Klipper's step-generation windows (see
    :class:`StepGenerator`).
    """
    if rails is None:
        rails = rails_for(machine, klipper_names, kinematics=kinematics)
    if settings is None and machine is not None:
        settings = machine.limits_row()
    parts: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in rails]

    def sink(si, t, d):
        parts[si].append((t.copy(), d.copy()))

    gen = StepGenerator(rails, sink, sds_filter_t=sds_filter_t, settings=settings, flush_times=flush_times)
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
