"""Rotary delta kinematics (Klipper's kinematics/rotary_delta.py, chelper/kin_rotary_delta.c) as a plug-in.

Three upper arms turn on shoulders at ``shoulder_radius`` from the centre and ``shoulder_height`` above Z = 0, at
angles 30°, 150°, 270° (default); a lower arm joins each elbow to the effector. Motors ``stepper_a/b/c`` are the
upper-arm angles in rad. For arm i at angle a_i and effector (x, y, z), in the shoulder's frame
sjz = y·cos a − x·sin a, sjx = x·cos a + y·sin a − shoulder_radius, sjy = z − shoulder_height, and the angle
solves the two-arm triangle (kin_rotary_delta.c's rotary_two_arm_calc with lower_arm² − sjz²).

Limits (Klipper's ``RotaryDeltaKinematics.check_move``), per move: the end must lie within
max_xy2 = min(shoulder_radius + upper_arm, lower_arm − shoulder_radius)², tapering to (max_z − z)² above
limit_z, and between minimum_z_position and max_z (except a move to the home XY below the home height);
a move with any Z motion is capped at max_z_velocity **without** the Z ratio and keeps its acceleration
(Klipper's ``limit_speed(max_z_velocity, move.accel)``; there is no max_z_accel). Klipper checks a move in
full only after a Z move or a position set; a move it skips ends inside the limit of the last full check,
at the same height, so checking every move gives the same answer.

``machine.kinematics_params``: ``steps_per_rad`` (a, b, c), ``shoulder_radius``, ``shoulder_height``,
``upper_arm_length``/``lower_arm_length``/``angle`` (three each), ``position_endstop`` (three),
``minimum_z_position``, ``max_z_velocity``.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..errors import ConfigError
from .plugin import ERR_OUT_OF_RANGE, MV_X1, MV_Y1, MV_Z0, MV_Z1, Plugin, register

NAME = "rotary_delta"
ARMS = ("a", "b", "c")
DEFAULT_ANGLES = (30.0, 150.0, 270.0)

# ik parameters per arm
A_COS, A_SIN, A_SHOULDER_R, A_SHOULDER_H, A_UPPER2, A_LOWER2 = range(6)
# hook parameters
P_MAX_XY2, P_LIMIT_Z, P_MAX_Z, P_MIN_Z, P_HOME_X, P_HOME_Y, P_HOME_Z, P_MAX_Z_V = range(8)


@njit(cache=True)
def rotary_two_arm_calc(dx, dy, upper_arm2, lower_arm2):
    """rad: the upper arm's angle for an effector joint at (dx, dy) from the shoulder (the two-arm triangle,
    kin_rotary_delta.c)."""
    inv_dy = 1.0 / dy
    c1 = 0.5 * inv_dy * (dx * dx + dy * dy + upper_arm2 - lower_arm2)
    c2 = dx * inv_dy
    scale = c2 * c2 + 1.0
    scaled_elbow_x = c1 * c2 + math.sqrt(scale * upper_arm2 - c1 * c1)
    scaled_elbow_y = c1 * scale - c2 * scaled_elbow_x
    return math.atan2(scaled_elbow_y, scaled_elbow_x)


@njit(cache=True)
def arm_angle(x, y, z, params):
    """rad: upper-arm angle of the arm whose A_* parameters are ``params``."""
    sjz = y * params[A_COS] - x * params[A_SIN]
    sjx = x * params[A_COS] + y * params[A_SIN] - params[A_SHOULDER_R]
    sjy = z - params[A_SHOULDER_H]
    return rotary_two_arm_calc(sjx, sjy, params[A_UPPER2], params[A_LOWER2] - sjz * sjz)


@njit(cache=True)
def check_move(move, params):
    """rotary_delta.py check_move (module docstring)."""
    x1 = move[MV_X1]
    y1 = move[MV_Y1]
    end_z = move[MV_Z1]
    end_xy2 = x1 ** 2 + y1 ** 2
    limit_xy2 = params[P_MAX_XY2]
    if end_z > params[P_LIMIT_Z]:
        limit_xy2 = min(limit_xy2, (params[P_MAX_Z] - end_z) ** 2)
    if end_xy2 > limit_xy2 or end_z > params[P_MAX_Z] or end_z < params[P_MIN_Z]:
        if (x1 != params[P_HOME_X] or y1 != params[P_HOME_Y] or end_z < params[P_MIN_Z]
                or end_z > params[P_HOME_Z]):
            return math.inf, math.inf, ERR_OUT_OF_RANGE
    if move[MV_Z1] != move[MV_Z0]:
        return params[P_MAX_Z_V], math.inf, 0
    return math.inf, math.inf, 0


def _three(machine, key, default=None):
    v = machine.kinematics_params.get(key, default)
    if v is None:
        raise ConfigError(f"kinematics_params.{key}: required by kinematics {NAME!r} (three values: arms a, b, c)")
    vals = tuple(float(x) for x in (v if isinstance(v, (list, tuple)) else (v, v, v)))
    if len(vals) != 3 or not all(math.isfinite(x) for x in vals):
        raise ConfigError(f"kinematics_params.{key}: three finite numbers (arms a, b, c), got {v!r}")
    return vals


def _one(machine, key, default=None):
    v = machine.kinematics_params.get(key, default)
    if v is None:
        raise ConfigError(f"kinematics_params.{key}: required by kinematics {NAME!r}")
    return float(v)


def arm_params(machine, i: int) -> np.ndarray:
    """The A_* parameters of arm i."""
    ang = math.radians(_three(machine, "angle", DEFAULT_ANGLES)[i])
    ua = _three(machine, "upper_arm_length")[i]
    la = _three(machine, "lower_arm_length")[i]
    return np.array([math.cos(ang), math.sin(ang), _one(machine, "shoulder_radius"),
                     _one(machine, "shoulder_height"), ua * ua, la * la])


def geometry(machine) -> dict:
    """Klipper's derived numbers: endstop angles, max_xy2, limit_z, max_z, min_z, home position (mm, rad).
    The home position is taken as (0, 0, max_z), exact when the three endstops are equal (Klipper solves the
    forward kinematics; it only matters for the homing-move exception)."""
    sr = _one(machine, "shoulder_radius")
    sh = _one(machine, "shoulder_height")
    ups = _three(machine, "upper_arm_length")
    lows = _three(machine, "lower_arm_length")
    endstops = _three(machine, "position_endstop")
    eangles = [arm_angle.py_func(0.0, 0.0, ep, arm_params(machine, i)) for i, ep in enumerate(endstops)]
    max_z = min(endstops)
    max_xy2 = min(min(sr + ua for ua in ups), min(la - sr for la in lows)) ** 2
    # the elbow's height: the shoulder's plus the upper arm's rise at the endstop angle
    arm_z = [sh + ua * math.sin(ea) for ua, ea in zip(ups, eangles)]
    limit_z = min(az - la for az, la in zip(arm_z, lows))
    return {"endstop_angles": eangles, "max_xy2": max_xy2, "limit_z": limit_z, "max_z": max_z,
            "min_z": _one(machine, "minimum_z_position", 0.0), "home": (0.0, 0.0, max_z)}


def params(machine) -> np.ndarray:
    g = geometry(machine)
    return np.array([g["max_xy2"], g["limit_z"], g["max_z"], g["min_z"], *g["home"],
                     _one(machine, "max_z_velocity", machine.max_velocity)])


def from_klipper(cfg, machine) -> None:
    """Read [printer] shoulder_radius/height, minimum_z_position, max_z_velocity and [stepper_a|b|c]."""
    from ..config.klipper import klipper_steps_per_rad

    kp = machine.kinematics_params
    for t in ARMS:
        if not cfg.has(f"stepper_{t}"):
            raise ConfigError(f"[stepper_{t}] section is required (kinematics: rotary_delta)", cfg.main)
    kp["steps_per_rad"] = [klipper_steps_per_rad(cfg, f"stepper_{t}") for t in ARMS]
    kp["shoulder_radius"] = cfg.get_float("printer", "shoulder_radius", required=True, above=0.0)
    kp["shoulder_height"] = cfg.get_float("printer", "shoulder_height", required=True, above=0.0)
    for key in ("upper_arm_length", "lower_arm_length"):
        first = cfg.get_float("stepper_a", key, required=True, above=0.0)
        kp[key] = [first] + [cfg.get_float(f"stepper_{t}", key, first, above=0.0) for t in "bc"]
    kp["angle"] = [cfg.get_float(f"stepper_{t}", "angle", a) for t, a in zip(ARMS, DEFAULT_ANGLES)]
    end_a = cfg.get_float("stepper_a", "position_endstop", required=True)
    kp["position_endstop"] = [end_a] + [cfg.get_float(f"stepper_{t}", "position_endstop", end_a) for t in "bc"]
    kp["minimum_z_position"] = cfg.get_float("printer", "minimum_z_position", 0.0, maxval=min(kp["position_endstop"]))
    kp["max_z_velocity"] = cfg.get_float("printer", "max_z_velocity", machine.max_velocity, above=0.0,
                                         maxval=machine.max_velocity)
    # no Z-ratio rule (the hook's flat cap instead) and no max_z_accel: the Z axis has no limits of its own
    z = machine.axes["z"]
    z.max_velocity = z.max_accel = math.inf
    for a in "xyz":
        machine.axes[a].position_min, machine.axes[a].position_max = -math.inf, math.inf


PLUGIN = Plugin({t: arm_angle for t in ARMS},
                {t: (lambda m, i=i: _three(m, "steps_per_rad")[i]) for i, t in enumerate(ARMS)},
                params=params, check_move=check_move, motor_params={t: (lambda m, i=i: arm_params(m, i))
                                                                    for i, t in enumerate(ARMS)},
                klipper_names={t: f"stepper_{t}" for t in ARMS}, from_klipper=from_klipper)
PLUGIN._builtin_of = NAME
register(NAME, PLUGIN)
rails = PLUGIN.rails
