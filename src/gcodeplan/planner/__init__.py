"""Look-ahead planner: MOVE rows → PLAN rows (trapezoids), PLAN → SEGMENT pieces, sampling.

Public API::

    plan = plan_moves(moves, limits, machine, policy=None)     # PLAN_DTYPE, 1:1 with moves
    sp = StreamPlanner(machine, policy=None)                    # same plan, bounded memory
    segs = to_segments(moves, plan, first_index=0)              # SEGMENT_DTYPE pieces
    pos, vel, acc, jerk = sample_segments(segs, times)          # (len(times), 4) each, x y z e

Policies (``POLICIES``): 'klipper' (Klipper's toolhead planner, exact), 'junction-deviation'
(grbl / Marlin 2), 'classic-jerk' (Marlin classic jerk), 'exact-stop' (G61), and 'blend'
(parabolic blends, :mod:`gcodeplan.planner.blend`). A finite ``max_jerk`` in the limits, or
``jerk=``, selects S-curves (:mod:`gcodeplan.planner.scurve`). ``StreamPlanner`` streams every
policy and S-curves with a bounded window, bit-identical to whole-program planning; for blends
and S-curves ask ``sp.segments_for(moves, plan, first_index)`` for each emitted pair (their pieces
are not trapezoids) before the next ``feed``/``finish``.
"""
from __future__ import annotations

import numpy as np

from ..machine import POLICIES
from .passes import plan_from_prep
from .prepare import POLICY_BLEND, POLICY_LINUXCNC, PREP_DTYPE, policy_code, prepare
from .sampling import sample_segments
from .segments import to_segments
from .blend import plan_blend
from .scurve import plan_scurve, scurve_jerk
from .stream import StreamPlanner, no_blend_with_jerk

__all__ = ["plan_moves", "StreamPlanner", "to_segments", "sample_segments", "POLICIES", "prepare",
           "PREP_DTYPE", "plan_from_prep"]


def _plan_only(result):
    """blend / scurve return (PLAN rows, SEGMENT rows); plan_moves returns the PLAN rows."""
    return result[0] if isinstance(result, tuple) else result


def plan_moves(moves: np.ndarray, limits: np.ndarray, machine, policy: str | None = None,
               jerk: float | None = None) -> np.ndarray:
    """Plan every move: PLAN_DTYPE rows aligned 1:1 with ``moves``; the first move starts at t = 0.

    ``policy`` None = ``machine.junction_policy``. Full stops at dwell/wait rows (which then add
    their dwell_t), after ``exact_stop`` moves and at the end.
    """
    name = policy or machine.junction_policy
    pcode = policy_code(name)
    moves = np.asarray(moves)
    limits = np.asarray(limits)
    j = scurve_jerk(moves, limits, jerk)
    if j is not None:
        no_blend_with_jerk(policy_code(name))
        return _plan_only(plan_scurve(moves, limits, machine, j, policy=name))
    if pcode == POLICY_BLEND:
        return _plan_only(plan_blend(moves, limits, machine))
    if pcode == POLICY_LINUXCNC:
        from .linuxcnc import plan_linuxcnc

        return plan_linuxcnc(moves, limits, machine)[0]
    prep = prepare(moves, limits, machine, name)
    plan, _ = plan_from_prep(moves, prep, pcode)
    return plan


def plan_with_segments(moves: np.ndarray, limits: np.ndarray, machine, policy: str | None = None,
                       jerk: float | None = None, first_index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(PLAN rows, SEGMENT rows) with the exact pieces of whichever planner ran: blends and S-curve
    phases are not trapezoid pieces, so ``to_segments`` cannot rebuild them from the PLAN rows."""
    name = policy or machine.junction_policy
    moves = np.asarray(moves)
    limits = np.asarray(limits)
    j = scurve_jerk(moves, limits, jerk)
    if j is not None:
        no_blend_with_jerk(policy_code(name))
        return plan_scurve(moves, limits, machine, j, first_move=first_index, policy=name)
    if policy_code(name) == POLICY_BLEND:
        return plan_blend(moves, limits, machine, first_move=first_index)
    if policy_code(name) == POLICY_LINUXCNC:
        from .linuxcnc import plan_linuxcnc

        return plan_linuxcnc(moves, limits, machine, first_move=first_index)
    plan = plan_moves(moves, limits, machine, name)
    return plan, to_segments(moves, plan, first_index)
