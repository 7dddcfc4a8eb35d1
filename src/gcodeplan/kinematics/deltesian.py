"""Deltesian kinematics (Klipper's kinematics/deltesian.py, chelper/kin_deltesian.c) as a plug-in.

Two towers at x = −arm_x_length (left) and +arm_x_length (right) carry carriages whose arms (arm_length)
meet at the effector; Y is a plain axis. Motors: ``stepper_left`` = √(arm² − (x + arm_x)²) + z,
``stepper_right`` = √(arm² − (x − arm_x)²) + z (carriage heights, mm), ``stepper_y`` = y.

Limits (Klipper's ``DeltesianKinematics.check_move``): X within the kinematic range (from min_angle, or
±print_width/2), Y within its rail (the machine's Y axis limits), Z within [minimum_z_position, z_max], z_max
adapted to the end's X at the very top; the cartesian Z-ratio rule (the machine's Z axis limits); and slow
zones: a move with X motion reaching beyond √slow_x2 gets speed and accel ≤ ½ of the config's max_velocity
and max_accel, beyond √very_slow_x2 ≤ ¼.

**Klipper 0.13 (84104bbbd) crashes in the slow zones**: its check_move reads ``self.max_velocity``, which it
never sets, so the first move entering a slow zone stops the printer with an internal error. gcodeplan applies
the limit Klipper's code means (the config's maxima × ½ or × ¼) instead of refusing the move.

``machine.kinematics_params``: ``arm_length``/``arm_x_length`` (left, right), ``position_endstop`` (left,
right), ``steps_per_mm`` (left, right), ``min_angle`` (°), ``print_width`` (mm, 0 = from the kinematics),
``slow_ratio``, ``minimum_z_position``, ``max_velocity``/``max_accel`` (the config's).
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..errors import ConfigError
from .plugin import ERR_OUT_OF_RANGE, MV_X0, MV_X1, MV_Y0, MV_Y1, MV_Z1, Plugin, register

NAME = "deltesian"
MIN_ANGLE = 5.0
SLOW_RATIO = 3.0

P_X_MIN, P_X_MAX, P_Z_MIN, P_Z_MAX, P_HOME_Z, P_SLOW_X2, P_VSLOW_X2, P_MAX_V, P_MAX_A = range(9)
P_ARM2_L, P_ARM2_R, P_ARM_X_L, P_ARM_X_R, P_ABS_L, P_ABS_R = range(9, 15)


@njit(cache=True)
def carriage_height(x, y, z, params):
    """mm: a tower carriage's height, √(arm² − (x − tower x)²) + z (params: arm², tower x)."""
    dx = x - params[1]
    return math.sqrt(params[0] - dx * dx) + z


@njit(cache=True)
def pillars_z_max(x, params):
    """mm: the highest Z the carriages allow at X = x (deltesian.py _pillars_z_max)."""
    dz_l = math.sqrt(params[P_ARM2_L] - (params[P_ARM_X_L] + x) ** 2)
    dz_r = math.sqrt(params[P_ARM2_R] - (params[P_ARM_X_R] - x) ** 2)
    return min(params[P_ABS_L] - dz_l, params[P_ABS_R] - dz_r)


@njit(cache=True)
def check_move(move, params):
    """deltesian.py check_move (module docstring), with the slow zones' intended limit."""
    x1 = move[MV_X1]
    z1 = move[MV_Z1]
    dx = x1 - move[MV_X0]
    homing = x1 == 0.0 and z1 == params[P_HOME_Z] and move[MV_Y1] == move[MV_Y0]
    z_max = params[P_Z_MAX]
    if not homing and z1 > z_max:
        z_max = pillars_z_max(x1, params)
    if not homing:
        if dx != 0.0 and (x1 < params[P_X_MIN] or x1 > params[P_X_MAX]):
            return math.inf, math.inf, ERR_OUT_OF_RANGE
        if z1 != move[2] and (z1 < params[P_Z_MIN] or z1 > z_max):
            return math.inf, math.inf, ERR_OUT_OF_RANGE
    if dx != 0.0 and params[P_SLOW_X2] > 0.0 and params[P_VSLOW_X2] > 0.0:
        move_x2 = max(move[MV_X0] ** 2, x1 ** 2)
        if move_x2 > params[P_VSLOW_X2]:
            return params[P_MAX_V] * 0.25, params[P_MAX_A] * 0.25, 0
        if move_x2 > params[P_SLOW_X2]:
            return params[P_MAX_V] * 0.50, params[P_MAX_A] * 0.50, 0
    return math.inf, math.inf, 0


def _two(machine, key, default=None):
    v = machine.kinematics_params.get(key, default)
    if v is None:
        raise ConfigError(f"kinematics_params.{key}: required by kinematics {NAME!r} (left, right)")
    vals = tuple(float(x) for x in (v if isinstance(v, (list, tuple)) else (v, v)))
    if len(vals) != 2 or not all(math.isfinite(x) for x in vals):
        raise ConfigError(f"kinematics_params.{key}: two finite numbers (left, right), got {v!r}")
    return vals


def geometry(machine) -> dict:
    """Klipper's derived numbers (deltesian.py __init__): X limits, Z range, home Z, slow-zone x², abs endstops."""
    kp = machine.kinematics_params
    arm = _two(machine, "arm_length")
    arm_x = _two(machine, "arm_x_length")
    arm2 = [a ** 2 for a in arm]
    cos_angle = math.cos(math.radians(float(kp.get("min_angle", MIN_ANGLE))))
    x_kin_min = math.ceil(-min(arm_x[0], cos_angle * arm[1] - arm_x[1]))
    x_kin_max = math.floor(min(arm_x[1], cos_angle * arm[0] - arm_x[0]))
    pw = float(kp.get("print_width", 0.0) or 0.0)
    x_lim = (-pw * 0.5, pw * 0.5) if pw else (x_kin_min, x_kin_max)
    pmax = _two(machine, "position_endstop")
    abs_endstop = [p + math.sqrt(a2 - ax ** 2) for p, a2, ax in zip(pmax, arm2, arm_x)]
    # home Z: deltesian.py _actuator_to_cartesian of the endstops (trilateration along the pivots)
    dx, dz = sum(arm_x), abs_endstop[1] - abs_endstop[0]
    pivots = math.sqrt(dx ** 2 + dz ** 2)
    xt = (pivots ** 2 + arm2[0] - arm2[1]) / (2 * pivots)
    zt = math.sqrt(arm2[0] - xt ** 2)
    home_z = xt * dz / pivots - zt * dx / pivots + abs_endstop[0]
    p = np.zeros(15)
    p[P_ARM2_L], p[P_ARM2_R], p[P_ARM_X_L], p[P_ARM_X_R] = arm2[0], arm2[1], arm_x[0], arm_x[1]
    p[P_ABS_L], p[P_ABS_R] = abs_endstop
    z_max = min(pillars_z_max.py_func(x, p) for x in x_lim)
    slow_ratio = float(kp.get("slow_ratio", SLOW_RATIO))
    slow_x2 = very_slow_x2 = 0.0
    if slow_ratio > 0.0:
        sr2 = slow_ratio ** 2
        slow_x2 = min(math.sqrt((sr2 * a2) / (sr2 + 1)) - axl for a2, axl in zip(arm2, arm_x)) ** 2
        very_slow_x2 = min(math.sqrt((2 * sr2 * a2) / (2 * sr2 + 1)) - axl for a2, axl in zip(arm2, arm_x)) ** 2
    return {"x_limits": x_lim, "z_limits": (float(kp.get("minimum_z_position", 0.0)), z_max), "home_z": home_z,
            "slow_x2": slow_x2, "very_slow_x2": very_slow_x2, "abs_endstops": abs_endstop, "arm2": arm2,
            "arm_x": arm_x, "params": p}


def params(machine) -> np.ndarray:
    g = geometry(machine)
    p = g["params"]
    kp = machine.kinematics_params
    p[P_X_MIN], p[P_X_MAX] = g["x_limits"]
    p[P_Z_MIN], p[P_Z_MAX] = g["z_limits"]
    p[P_HOME_Z], p[P_SLOW_X2], p[P_VSLOW_X2] = g["home_z"], g["slow_x2"], g["very_slow_x2"]
    p[P_MAX_V] = float(kp.get("max_velocity", machine.max_velocity))
    p[P_MAX_A] = float(kp.get("max_accel", machine.max_accel))
    return p


def tower_params(machine, i: int) -> np.ndarray:
    arm = _two(machine, "arm_length")[i]
    arm_x = _two(machine, "arm_x_length")[i]
    return np.array([arm * arm, -arm_x if i == 0 else arm_x])


def from_klipper(cfg, machine) -> None:
    """Read [stepper_left], [stepper_right] (arm lengths, endstops), [stepper_y] and the [printer] options."""
    from ..config.klipper import _klipper_steps_per_mm, klipper_rail

    kp = machine.kinematics_params
    for s in ("stepper_left", "stepper_right", "stepper_y"):
        if not cfg.has(s):
            raise ConfigError(f"[{s}] section is required (kinematics: deltesian)", cfg.main)
    kp["steps_per_mm"] = [_klipper_steps_per_mm(cfg, s) for s in ("stepper_left", "stepper_right")]
    ax_l = cfg.get_float("stepper_left", "arm_x_length", required=True, above=0.0)
    ax_r = cfg.get_float("stepper_right", "arm_x_length", ax_l, above=0.0)
    arm_l = cfg.get_float("stepper_left", "arm_length", required=True, above=ax_l)
    arm_r = cfg.get_float("stepper_right", "arm_length", arm_l, above=ax_r)
    kp["arm_x_length"], kp["arm_length"] = [ax_l, ax_r], [arm_l, arm_r]
    end_l = cfg.get_float("stepper_left", "position_endstop", required=True)
    kp["position_endstop"] = [end_l, cfg.get_float("stepper_right", "position_endstop", end_l)]
    kp["min_angle"] = cfg.get_float("printer", "min_angle", MIN_ANGLE, minval=0.0, maxval=90.0)
    kp["print_width"] = cfg.get_float("printer", "print_width", 0.0, minval=0.0)
    kp["slow_ratio"] = cfg.get_float("printer", "slow_ratio", SLOW_RATIO, minval=0.0)
    kp["minimum_z_position"] = cfg.get_float("printer", "minimum_z_position", 0.0)
    kp["max_velocity"], kp["max_accel"] = machine.max_velocity, machine.max_accel
    machine.axes["y"].steps_per_mm = klipper_rail(cfg, "stepper_y", machine.axes["y"])
    for a in "xz":       # X and Z ranges: the hook's (Z's top depends on X)
        machine.axes[a].position_min, machine.axes[a].position_max = -math.inf, math.inf


PLUGIN = Plugin({"left": carriage_height, "right": carriage_height, "y": (0.0, 1.0, 0.0)},
                {"left": lambda m: _two(m, "steps_per_mm")[0], "right": lambda m: _two(m, "steps_per_mm")[1]},
                params=params, check_move=check_move,
                motor_params={"left": lambda m: tower_params(m, 0), "right": lambda m: tower_params(m, 1)},
                klipper_names={"left": "stepper_left", "right": "stepper_right", "y": "stepper_y"},
                from_klipper=from_klipper)
PLUGIN._builtin_of = NAME
register(NAME, PLUGIN)
rails = PLUGIN.rails
