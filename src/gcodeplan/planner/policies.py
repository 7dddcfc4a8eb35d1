"""Junction policies as plug-ins: one registry for the built-in corner rules and the user's own.

A policy is a numba-compiled function ``cap_v2(prev, cur, lim) -> float``: the highest speed² (mm²/s²)
at which the tool may pass from move ``prev`` to move ``cur``. ``prev`` and ``cur`` are float64 vectors
indexed by the constants below (unit direction per mm of path, length, acceleration, cruise cap, ...);
``lim`` is the LIMITS row in force for ``cur`` (float64, indexed by :data:`LIMIT_INDEX`). 0 means a
stop at the corner, ``inf`` no cap of its own; NaN or a negative value is an error naming the policy
and the line (a rule's bug must not pass for a full stop). The planner
then applies what every policy shares: both moves' cruise caps and the forward reach
(``prev`` start speed² + 2·d·a), and plans the trapezoids with look-ahead as Klipper's toolhead does.

    import numba, gcodeplan as gp
    from gcodeplan.planner.policies import U_X, U_Y, U_Z, ACCEL, KINEMATIC

    @njit
    def stop_on_sharp_corners(prev, cur, lim):
        cos_turn = prev[U_X] * cur[U_X] + prev[U_Y] * cur[U_Y] + prev[U_Z] * cur[U_Z]
        if prev[KINEMATIC] == 0.0 or cur[KINEMATIC] == 0.0 or cos_turn < 0.5:
            return 0.0
        return cur[ACCEL] * 0.05 * (1.0 + cos_turn)      # any rule you like

    gp.register_policy("gentle", stop_on_sharp_corners)
    gp.estimate("part.gcode", policy="gentle")          # or: gcodeplan estimate --policy gentle

The built-in policies go through the same registry, each with its own cap function (tests plan every
corpus file through :func:`cap_junction_kernel` with these functions and get the built-in kernel's
plans bit for bit); the planner runs their pre-compiled kernel for speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .. import _jit
from .._jit import njit
import numpy as np

from ..errors import ConfigError, GcodeError
from ..machine import POLICIES
from ..schema import LIMITS_DTYPE
from .junctions import (jd_junction_v2, klipper_centripetal_v2, klipper_extruder_corner_v2,
                        marlin_jerk_junction_v, marlin_small_segment_v2)

# ---------------------------------------------------------------- the move vector a cap function sees
U_X, U_Y, U_Z, U_E = 0, 1, 2, 3   # direction: axis distance per mm of path (E: filament mm per mm)
MOVE_D = 4          # mm, path length (|dE| for an extrude-only move)
ACCEL = 5           # mm/s², the move's acceleration after every limit
MAX_CRUISE_V2 = 6   # mm²/s², the move's cruise cap after every speed limit
DELTA_V2 = 7        # mm²/s², 2·move_d·accel: what the move can gain from start to end
JUNCTION_DEV = 8    # mm, the junction deviation the move uses (Klipper: derived from square_corner_velocity)
STOP_V2 = 9         # mm²/s², speed² allowed next to a full stop (classic jerk's safe speed², else 0)
KINEMATIC = 10      # 1.0 when the move has XYZ motion, 0.0 for extrude-only
MOVE_VECTOR_LEN = 11

#: LIMITS field name → column of the ``lim`` row a cap function receives
LIMIT_INDEX = {name: k for k, name in enumerate(LIMITS_DTYPE.names)}
_L_JD = LIMIT_INDEX["junction_dev"]
_L_ICV = LIMIT_INDEX["icv"]
_L_JERK0 = LIMIT_INDEX["jerk_x"]


# ---------------------------------------------------------------- the built-in rules as cap functions
@njit(cache=True)
def klipper_cap_v2(prev, cur, lim):
    """Klipper's toolhead.Move.calc_junction (without the shared caps): extruder corner speed, the
    junction-deviation circle of each move and the centripetal half-move rule (docs/design.md)."""
    if prev[KINEMATIC] == 0.0 or cur[KINEMATIC] == 0.0:
        return 0.0
    cos_theta = -(cur[U_X] * prev[U_X] + cur[U_Y] * prev[U_Y] + cur[U_Z] * prev[U_Z])
    e_v2 = klipper_extruder_corner_v2(lim[_L_ICV], cur[U_E], prev[U_E], cur[MAX_CRUISE_V2])
    v2 = min(e_v2, 999999999.9)
    return min(v2, klipper_centripetal_v2(cos_theta, cur[JUNCTION_DEV], cur[ACCEL], cur[DELTA_V2],
                                          prev[JUNCTION_DEV], prev[ACCEL], prev[DELTA_V2]))


@njit(cache=True)
def junction_deviation_cap_v2(prev, cur, lim):
    """grbl / Marlin 2 junction deviation with Marlin's small-segment rule (docs/design.md)."""
    if prev[KINEMATIC] == 0.0 or cur[KINEMATIC] == 0.0:
        return 0.0
    cos_theta = -(cur[U_X] * prev[U_X] + cur[U_Y] * prev[U_Y] + cur[U_Z] * prev[U_Z])
    v2 = jd_junction_v2(cos_theta, cur[ACCEL], cur[JUNCTION_DEV])
    return min(v2, marlin_small_segment_v2(cos_theta, cur[MOVE_D], cur[ACCEL]))


@njit(cache=True)
def classic_jerk_cap_v2(prev, cur, lim):
    """Marlin's classic jerk: per-axis speed jumps (E included), also next to extrude-only moves."""
    jv = marlin_jerk_junction_v(math.sqrt(prev[MAX_CRUISE_V2]), math.sqrt(cur[MAX_CRUISE_V2]),
                                prev[U_X], prev[U_Y], prev[U_Z], prev[U_E],
                                cur[U_X], cur[U_Y], cur[U_Z], cur[U_E],
                                lim[_L_JERK0], lim[_L_JERK0 + 1], lim[_L_JERK0 + 2], lim[_L_JERK0 + 3],
                                math.sqrt(prev[STOP_V2]), math.sqrt(cur[STOP_V2]))
    return jv * jv


@njit(cache=True)
def exact_stop_cap_v2(prev, cur, lim):
    """G61 / G61.1: every corner at rest."""
    return 0.0


# ---------------------------------------------------------------- registry
@dataclass(frozen=True)
class Policy:
    """A registered junction policy.

    ``cap_v2``: the cap function (see the module docstring); ``moves_like``: the built-in policy whose
    per-move limits, flush rule and planning mode this one uses (for a custom policy
    'junction-deviation' unless given); ``code``: the built-in kernel's code (None for custom ones);
    ``stop_every_junction``: every move starts and ends at rest (exact stop).
    """

    name: str
    cap_v2: object
    moves_like: str
    code: int | None = None
    stop_every_junction: bool = False

    @property
    def builtin(self) -> bool:
        return self.code is not None


_REGISTRY: dict[str, Policy] = {}


def _register_builtins() -> None:
    # a built-in's kernel code is its index in machine.POLICIES (prepare.policy_code, prepare's POLICY_* codes)
    for name, fn in (("klipper", klipper_cap_v2),
                     ("junction-deviation", junction_deviation_cap_v2),
                     ("classic-jerk", classic_jerk_cap_v2),
                     ("blend", junction_deviation_cap_v2),
                     ("exact-stop", exact_stop_cap_v2),
                     # LinuxCNC's planner (planner/linuxcnc.py) does its own corners; the cap is unused
                     ("linuxcnc", junction_deviation_cap_v2)):
        _REGISTRY[name] = Policy(name, fn, name, POLICIES.index(name), stop_every_junction=(name == "exact-stop"))


def register_policy(name: str, cap_v2, *, moves_like: str = "junction-deviation", replace: bool = False) -> Policy:
    """Add a junction policy usable everywhere a policy name is (``policy=`` in the API, ``--policy``).

    ``cap_v2``: a ``numba.njit`` function ``(prev, cur, lim) -> mm²/s²`` (module docstring). A plain
    Python function is compiled with ``numba.njit``; returning NaN or a negative number is an error
    naming the policy and the G-code line when it plans. ``moves_like``: the built-in whose per-move limits
    and flush rule apply ('klipper', 'junction-deviation' or 'classic-jerk'). Built-in names cannot be
    replaced; a custom name can with ``replace=True``. Returns the :class:`Policy`.
    """
    if not isinstance(name, str) or not name.strip() or any(c.isspace() for c in name):
        raise ConfigError(f"register_policy: the name must be a non-empty word, got {name!r}")
    old = _REGISTRY.get(name)
    if old is not None and (old.builtin or not replace):
        raise ConfigError(f"register_policy: policy {name!r} exists" + ("" if old.builtin else " (replace=True)"))
    base = _REGISTRY.get(moves_like)
    if base is None or not base.builtin or moves_like in ("blend", "exact-stop"):
        raise ConfigError(f"register_policy: moves_like must be 'klipper', 'junction-deviation' or 'classic-jerk', "
                          f"got {moves_like!r}")
    if not callable(cap_v2):
        raise ConfigError("register_policy: cap_v2 must be a function (prev, cur, lim) -> v² (mm²/s²)")
    numba = _jit.numba_module()             # a plug-in is numba code: compile it now
    if not _jit.is_kernel(cap_v2):
        cap_v2 = numba.njit(cap_v2)
    pol = Policy(name, cap_v2, moves_like, None)
    _REGISTRY[name] = pol
    return pol


def unregister_policy(name: str) -> None:
    """Remove a custom policy (built-ins stay)."""
    pol = _REGISTRY.get(name)
    if pol is None or pol.builtin:
        raise ConfigError(f"unregister_policy: {name!r} is not a custom policy")
    del _REGISTRY[name]


def get_policy(name: str) -> Policy:
    """The registered policy ``name`` (ConfigError naming the known ones otherwise)."""
    pol = _REGISTRY.get(name)
    if pol is None:
        raise ConfigError(f"junction_policy: unknown policy {name!r} (one of {', '.join(policy_names())})")
    return pol


def policy_names() -> list[str]:
    """Every registered policy name, built-ins first."""
    return list(_REGISTRY)


def is_known(name: str) -> bool:
    return name in _REGISTRY


# ---------------------------------------------------------------- the generic junction pass
@njit(cache=False)
def _move_vector(pr, out):
    out[U_X] = pr.axes_r_x
    out[U_Y] = pr.axes_r_y
    out[U_Z] = pr.axes_r_z
    out[U_E] = pr.axes_r_e
    out[MOVE_D] = pr.move_d
    out[ACCEL] = pr.accel
    out[MAX_CRUISE_V2] = pr.max_cruise_v2
    out[DELTA_V2] = pr.delta_v2
    out[JUNCTION_DEV] = pr.junction_dev
    out[STOP_V2] = pr.stop_v2
    out[KINEMATIC] = 1.0 if pr.kinematic else 0.0


@njit(cache=False)
def _cap_junction_rows(moves, lim, cap_v2, stop_every, i_start, prev, stop_pending, prep):
    """:func:`cap_junction_kernel`'s loop; also returns the first row whose cap was NaN or negative
    (-1: none) and that cap."""
    kind_dwell = 3
    kind_wait = 4
    n = moves.shape[0]
    pv = np.empty(MOVE_VECTOR_LEN)
    cv = np.empty(MOVE_VECTOR_LEN)
    bad_row = -1
    bad_cap = 0.0
    for i in range(i_start, n):
        cur = prep[i]
        k = moves[i].kind
        if k == kind_dwell or k == kind_wait:
            cur.stop_before = True
            stop_pending = True
            continue
        if not cur.is_move:
            continue
        if prev < 0 or stop_pending or stop_every:
            cur.stop_before = True
            cur.max_start_v2 = cur.stop_v2
            cur.max_mcr_start_v2 = 0.0
        else:
            cur.stop_before = False
            pm = prep[prev]
            _move_vector(pm, pv)
            _move_vector(cur, cv)
            reach_v2 = pm.max_start_v2 + pm.delta_v2
            cap = cap_v2(pv, cv, lim[moves[i].limits])
            if not (cap >= 0.0):       # NaN or negative: no speed at all, the caller reports it
                if bad_row < 0:
                    bad_row = i
                    bad_cap = cap
                cap = 0.0
            v2 = min(cap, cur.max_cruise_v2, pm.max_cruise_v2, reach_v2)
            cur.max_start_v2 = v2
            cur.max_mcr_start_v2 = min(v2, pm.max_mcr_start_v2 + pm.mcr_delta_v2)
        prev = i
        stop_pending = moves[i].exact_stop != 0
    return prev, stop_pending, bad_row, bad_cap


def cap_junction_kernel(moves, lim, cap_v2, stop_every, i_start, prev, stop_pending, prep):
    """The junction pass of :mod:`gcodeplan.planner.prepare` with the cap taken from ``cap_v2``.

    Like the built-in ``_junction_kernel``: rows i_start.. of ``prep`` get their junction
    cap (``max_start_v2``, ``max_mcr_start_v2``, ``stop_before``); ``prev`` is the row of the previous
    move (-1: none), ``stop_pending`` a full stop since it. Returns (prev, stop_pending).
    A cap that is NaN or negative is no speed² at all (a bug in the rule, not a full stop): a
    :class:`~gcodeplan.errors.GcodeError` naming the policy and the move's line.
    """
    prev, stop_pending, bad_row, bad_cap = _cap_junction_rows(moves, lim, cap_v2, stop_every, i_start, prev,
                                                              stop_pending, prep)
    if bad_row >= 0:
        name = next((p.name for p in _REGISTRY.values() if p.cap_v2 is cap_v2), getattr(cap_v2, "__name__", "?"))
        what = "NaN" if math.isnan(bad_cap) else f"a negative speed² ({bad_cap!r} mm²/s²)"
        raise GcodeError(f"junction policy {name!r} returned {what} for the corner before this move: a cap "
                         f"function must return a speed² >= 0 mm²/s² (0 = stop there)",
                         line=int(moves[bad_row]["line"]))
    return prev, stop_pending


_register_builtins()

__all__ = ["Policy", "register_policy", "unregister_policy", "get_policy", "policy_names", "cap_junction_kernel",
           "klipper_cap_v2", "junction_deviation_cap_v2", "classic_jerk_cap_v2", "exact_stop_cap_v2",
           "U_X", "U_Y", "U_Z", "U_E", "MOVE_D", "ACCEL", "MAX_CRUISE_V2", "DELTA_V2", "JUNCTION_DEV", "STOP_V2",
           "KINEMATIC", "LIMIT_INDEX"]
