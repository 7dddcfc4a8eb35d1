"""StreamPlanner: plan a file chunk by chunk with a bounded look-ahead window.

Moves arrive in chunks (MOVE rows + the LIMITS table they index). The planner keeps only the
moves whose plan may still change and emits the others, so that the concatenation of everything
emitted is bit-identical to ``plan_moves`` on the whole file:

* a run of moves followed by a known full stop (dwell/wait row, exact-stop move) is flushed
  completely, as ``plan_moves`` does;
* the open run at the end is flushed lazily: Klipper's rule (up to the accelerating move before
  the 2nd "peak" from the end) for 'klipper', the last move whose start speed is pinned at its
  junction cap for the other trapezoid policies. Those moves' speeds depend only on moves that
  are already known.

Times continue from the previous emission (the first move starts at 0). 'blend' and S-curves are
planned by other modules that need the whole program: for them the stream buffers everything and
plans at ``finish()`` (memory is then not bounded).
"""
from __future__ import annotations

import numpy as np

from ..schema import MOVE_DTYPE, PLAN_DTYPE, concat_rows
from .passes import klipper_flush, layout_rows, plan_runs, speed_buffers, standard_flush
from .prepare import (POLICY_BLEND, POLICY_KLIPPER, PREP_DTYPE, policy_code, prepare_with_context, validate)
from .segments import to_segments


class StreamPlanner:
    """``for moves_out, plan_out in sp.feed(chunk, limits): ...`` then the same with ``sp.finish()``."""

    def __init__(self, machine, policy: str | None = None, jerk: float | None = None):
        self.machine = machine
        self.policy = policy or machine.junction_policy
        self._pcode = policy_code(self.policy)
        self._jerk = jerk
        self._moves = np.zeros(0, dtype=MOVE_DTYPE)      # pending rows (not emitted yet)
        self._prep = np.zeros(0, dtype=PREP_DTYPE)
        self._last_move: np.ndarray | None = None         # the last real move prepared (1 row)
        self._last_prep: np.ndarray | None = None
        self._stop_pending = True                         # a full stop precedes the next move
        self._clock = 0.0
        self._buffered: list[np.ndarray] = []             # blend / S-curve: whole program
        self._limits = None
        self._delegate = self._pcode == POLICY_BLEND or jerk is not None
        self._delegated_segments: np.ndarray | None = None

    # ------------------------------------------------------------------ public
    def feed(self, moves_chunk: np.ndarray, limits: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Add MOVE rows; return the (moves, plan) pieces whose plan can no longer change."""
        moves_chunk = np.asarray(moves_chunk)
        limits = np.asarray(limits)
        if len(moves_chunk) == 0:
            return []
        if self._delegate or self._wants_scurve(moves_chunk, limits):
            self._delegate = True
            self._buffered.append(moves_chunk.copy())
            self._limits = limits.copy()
            return []
        validate(moves_chunk, limits, self._pcode)
        prep, self._stop_pending = prepare_with_context(moves_chunk, limits, self._pcode, self._last_move,
                                                        self._last_prep, self._stop_pending)
        real = np.flatnonzero(prep["is_move"])
        if real.size:
            self._last_move = moves_chunk[real[-1]:real[-1] + 1].copy()
            self._last_prep = prep[real[-1]:real[-1] + 1].copy()
        self._moves = concat_rows(self._moves, moves_chunk)
        self._prep = concat_rows(self._prep, prep) if len(self._prep) else prep
        return self._emit(final=False)

    def finish(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Plan everything still pending, ending at rest."""
        if self._delegate:
            from . import plan_with_segments

            if not self._buffered:
                return []
            moves = np.concatenate(self._buffered)
            self._buffered = []
            plan, self._delegated_segments = plan_with_segments(moves, self._limits, self.machine, self.policy,
                                                                jerk=self._jerk)
            return [(moves, plan)]
        out = self._emit(final=True)
        self._last_move = self._last_prep = None
        self._stop_pending = True
        return out

    def segments_for(self, moves: np.ndarray, plan: np.ndarray, first_index: int = 0) -> np.ndarray:
        """SEGMENT rows of an emitted (moves, plan) pair: the delegated planner's own pieces for
        blends and S-curves (emitted whole at finish()), trapezoid pieces otherwise."""
        if self._delegated_segments is not None:
            return self._delegated_segments
        return to_segments(moves, plan, first_index)

    @property
    def pending(self) -> int:
        """Rows held in the look-ahead window."""
        return len(self._moves)

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _wants_scurve(moves: np.ndarray, limits: np.ndarray) -> bool:
        from . import _scurve_jerk

        return _scurve_jerk(moves, limits, None) is not None

    def _emit(self, final: bool) -> list[tuple[np.ndarray, np.ndarray]]:
        prep = self._prep
        rows = np.flatnonzero(prep["is_move"])
        m = len(rows)
        if len(self._moves) == 0:
            return []
        bufs = speed_buffers(m)
        # Moves before the open run (the one not yet followed by a known full stop) are final.
        if final or self._stop_pending:
            closed = m
        else:
            starts = np.flatnonzero(prep["stop_before"][rows])
            closed = int(starts[-1]) if starts.size else 0
        plan_runs(self._pcode, prep, rows, 0, closed, *bufs)
        done = closed
        if closed < m:
            flush = klipper_flush if self._pcode == POLICY_KLIPPER else standard_flush
            done = flush(prep, rows, closed, m, True, *bufs)
        # Emit every row before the first move still pending (dwell / dropped rows included).
        n_rows = len(self._moves) if done == m else int(rows[done])
        if n_rows == 0:
            return []
        moves_out = self._moves[:n_rows]
        plan, self._clock = layout_rows(moves_out, prep, n_rows, *bufs, self._clock)
        self._moves = self._moves[n_rows:].copy()
        self._prep = self._prep[n_rows:].copy()
        return [(moves_out, plan)]


def plan_stream(chunks, limits_for_chunk, machine, policy: str | None = None):
    """Convenience: run a StreamPlanner over an iterable of MOVE chunks; (moves, plan) concatenated."""
    sp = StreamPlanner(machine, policy)
    outs = []
    for chunk in chunks:
        outs.extend(sp.feed(chunk, limits_for_chunk))
    outs.extend(sp.finish())
    if not outs:
        return np.zeros(0, dtype=MOVE_DTYPE), np.zeros(0, dtype=PLAN_DTYPE)
    return np.concatenate([o[0] for o in outs]), np.concatenate([o[1] for o in outs])
