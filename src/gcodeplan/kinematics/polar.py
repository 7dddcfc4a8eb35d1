"""Polar kinematics (Klipper's kinematics/polar.py, chelper/kin_polar.c) as a plug-in.

A turntable (``stepper_bed``, its angle θ = atan2(y, x) in rad, followed continuously), a radial arm
(``stepper_arm``, r = √(x² + y²) mm) and Z. The centre is the toolhead origin (0, 0).

Limits (Klipper's ``PolarKinematics.check_move``), applied by the planner to every move:

* the end must lie within the arm's reach (x² + y² ≤ position_max² of ``stepper_arm``), a move with Z motion
  must end inside the Z rail's range: otherwise "Move out of range";
* Z: max_z_velocity / max_z_accel scaled by the Z ratio (the machine's Z axis limits, as cartesian);
* near the centre the bed turns fast: with d the distance from (0, 0) to the move's segment and
  ω = √(max_cruise_v2)/d, a move with ω > max_angular_velocity gets speed and accel caps of the config's
  max_velocity and max_accel times max_angular_velocity/ω. The caps use the config maxima, and the rule
  also fires on radial moves (Klipper's formula, kept).

``machine.kinematics_params``: ``bed_steps_per_rad``, ``arm_steps_per_mm``, ``arm_max`` (mm),
``z_min``/``z_max`` (mm), ``max_angular_velocity`` (rad/s, 0 = no rule), ``max_velocity``/``max_accel`` (the
config's, mm/s and mm/s²; default the machine's).
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from .plugin import ERR_OUT_OF_RANGE, MV_MAX_CRUISE_V2, MV_X0, MV_X1, MV_Y0, MV_Y1, MV_Z0, MV_Z1, Plugin, register

NAME = "polar"

P_ARM_MAX2, P_Z_MIN, P_Z_MAX, P_V_RAD_MAX, P_MAX_V, P_MAX_A = range(6)


@njit(cache=True)
def bed_angle(x, y, z, params):
    """rad: the turntable's angle, kin_polar.c's atan2(y, x) (the engine keeps it continuous)."""
    return math.atan2(y, x)


@njit(cache=True)
def arm_radius(x, y, z, params):
    """mm: the arm's extension, √(x² + y²)."""
    return math.sqrt(x * x + y * y)


@njit(cache=True)
def distance_to_center(x0, y0, x1, y1):
    """mm: the distance from (0, 0) to the segment (x0, y0)–(x1, y1), with polar.py's arithmetic."""
    ab_x = x1 - x0
    ab_y = y1 - y0
    ap_x = -x0
    ap_y = -y0
    dot = ab_x * ap_x + ab_y * ap_y
    ab_length = math.sqrt(ab_x ** 2 + ab_y ** 2)
    if dot <= 0:
        return math.sqrt(ap_x ** 2 + ap_y ** 2)
    if dot >= ab_length ** 2:
        return math.sqrt(x1 ** 2 + y1 ** 2)
    return abs(ab_x * ap_y - ab_y * ap_x) / ab_length


@njit(cache=True)
def check_move(move, params):
    """polar.py check_move: reach, Z range, the centre slow-down (module docstring)."""
    x1 = move[MV_X1]
    y1 = move[MV_Y1]
    if x1 ** 2 + y1 ** 2 > params[P_ARM_MAX2]:
        return math.inf, math.inf, ERR_OUT_OF_RANGE
    if move[MV_Z1] != move[MV_Z0]:
        if move[MV_Z1] < params[P_Z_MIN] or move[MV_Z1] > params[P_Z_MAX]:
            return math.inf, math.inf, ERR_OUT_OF_RANGE
    v_cap = math.inf
    a_cap = math.inf
    if (move[MV_X1] != move[MV_X0] or move[MV_Y1] != move[MV_Y0]) and params[P_V_RAD_MAX] != 0.0:
        min_dist = distance_to_center(move[MV_X0], move[MV_Y0], x1, y1)
        if min_dist != 0.0:
            v_angular = math.sqrt(move[MV_MAX_CRUISE_V2]) / min_dist
            if params[P_V_RAD_MAX] < v_angular:
                scale = params[P_V_RAD_MAX] / v_angular
                v_cap = params[P_MAX_V] * scale
                a_cap = params[P_MAX_A] * scale
    return v_cap, a_cap, 0


def _kp(machine, key, default=None):
    v = machine.kinematics_params.get(key, default)
    if v is None:
        from ..errors import ConfigError

        raise ConfigError(f"kinematics_params.{key}: required by kinematics {NAME!r}")
    return float(v)


def params(machine) -> np.ndarray:
    """The hook's parameters (P_* layout) from ``machine.kinematics_params``."""
    return np.array([_kp(machine, "arm_max") ** 2, _kp(machine, "z_min", -math.inf), _kp(machine, "z_max", math.inf),
                     _kp(machine, "max_angular_velocity", 0.0), _kp(machine, "max_velocity", machine.max_velocity),
                     _kp(machine, "max_accel", machine.max_accel)])


def from_klipper(cfg, machine) -> None:
    """Read [stepper_bed] (gear_ratio: rad), [stepper_arm], [stepper_z] and [printer] max_angular_velocity."""
    from ..config.klipper import klipper_rail, klipper_steps_per_rad

    kp = machine.kinematics_params
    kp["bed_steps_per_rad"] = klipper_steps_per_rad(cfg, "stepper_bed")
    arm = machine.axes["x"].__class__()
    kp["arm_steps_per_mm"] = klipper_rail(cfg, "stepper_arm", arm)
    kp["arm_max"] = arm.position_max
    z = machine.axes["z"]
    z.steps_per_mm = klipper_rail(cfg, "stepper_z", z)
    kp["z_min"], kp["z_max"] = z.position_min, z.position_max
    kp["max_angular_velocity"] = cfg.get_float("printer", "max_angular_velocity", 0.0, above=0.0) \
        if cfg.raw("printer", "max_angular_velocity") is not None else 0.0
    kp["max_velocity"], kp["max_accel"] = machine.max_velocity, machine.max_accel
    # the arm's reach is checked by the hook; Z by the hook too (only on moves with Z, as Klipper)
    for a in "xyz":
        machine.axes[a].position_min, machine.axes[a].position_max = -math.inf, math.inf


PLUGIN = Plugin({"bed": bed_angle, "arm": arm_radius, "z": (0.0, 0.0, 1.0)},
                {"bed": lambda m: _kp(m, "bed_steps_per_rad"), "arm": lambda m: _kp(m, "arm_steps_per_mm")},
                params=params, check_move=check_move, periods={"bed": 2.0 * math.pi},
                klipper_names={"bed": "stepper_bed", "arm": "stepper_arm", "z": "stepper_z"},
                from_klipper=from_klipper)
PLUGIN._builtin_of = NAME
register(NAME, PLUGIN)
rails = PLUGIN.rails
