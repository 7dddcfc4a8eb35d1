"""The machine file's field table (every key, its unit, its rule), the pure unit formulas, and validation.

The table ``FIELDS`` is the single source of truth for the TOML keys: loader, validation and writer use it
(documented in docs/machine.md)."""
from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

from ..errors import ConfigError
from ..marlin_build import rule_marlin_build
from ..machine import ACCELERATION_PROFILES, AXES, FIRMWARES, FLAVORS, KINEMATICS, POLICIES, SHAPER_TYPES, Axis, Machine, firmware_policy_conflict


# Kinematics Klipper and others offer that we know about but cannot plan yet.
UNSUPPORTED_KINEMATICS = {
    "none": "'none' kinematics cannot move",
}


# ============================================================================ pure formulas

def steps_per_mm_from_rotation(rotation_distance_mm: float, microsteps: int,
                               full_steps_per_rotation: int = 200, gear_ratio: float = 1.0) -> float:
    """Steps per mm of a stepper: full_steps · microsteps · gear_ratio / rotation_distance.

    Klipper's stepper model (docs/Rotation_Distance.md): one output rotation moves
    ``rotation_distance`` mm and takes ``full_steps·microsteps·gear_ratio`` microsteps.
    """
    return full_steps_per_rotation * microsteps * gear_ratio / rotation_distance_mm


def parse_gear_ratio(text: str) -> float:
    """Klipper's ``gear_ratio: a:b, c:d`` → ∏ a/b (each pair: driving teeth of the output : of the motor).

    Raises ValueError with a short reason on a malformed list.
    """
    result = 1.0
    pairs = [p.strip() for p in re.split(r"[,\n]", text) if p.strip()]
    if not pairs:
        raise ValueError("empty gear ratio")
    for pair in pairs:
        parts = pair.split(":")
        if len(parts) != 2:
            raise ValueError(f"expected 'a:b' pairs separated by commas, got {pair!r}")
        try:
            a, b = float(parts[0]), float(parts[1])
        except ValueError:
            raise ValueError(f"not a number in {pair!r}") from None
        if not (a > 0 and b > 0 and math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"both sides of {pair!r} must be positive numbers")
        result *= a / b
    return result


def klipper_extrude_ratio(cross_section_mm2: float, filament_diameter_mm: float) -> float:
    """mm of filament per mm of path for a given extruded cross-section: area / (π·(d/2)²).

    Klipper (kinematics/extruder.py) uses it twice: its default extrude-only limits scale the
    toolhead's limits by the ratio for the cross-section 4·nozzle², and ``max_extrude_ratio`` is
    the ratio for ``max_extrude_cross_section``.
    """
    return cross_section_mm2 / (math.pi * (filament_diameter_mm / 2.0) ** 2)


# ============================================================================ field table

# A rule checks one value and returns an error text ("must be ...") or None.
Rule = Callable[[Any], "str | None"]


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def rule_positive_or_inf(v: Any) -> str | None:
    if not is_number(v) or not v > 0:       # also rejects NaN
        return "must be a positive number (inf = no limit)"
    return None


# Sensible bounds (docs/machine.md "Bounds"). A speed below MIN_SPEED mm/s (3.6 mm an hour) or an accel below
# MIN_ACCEL mm/s² is a typo, not a machine: 1e-300 passes "> 0" yet makes the planner's v² and 1/a overflow.
MIN_SPEED = 1e-3          # mm/s
MIN_ACCEL = 1e-3          # mm/s² (and mm/s³ for max_jerk)
# A step of a nanometre is finer than any drive; above, one move holds more steps than memory (the step stage
# holds the steps of one motion piece at once, 9 bytes each) and a step file grows by terabytes.
MAX_STEPS_PER_MM = 1e6    # steps/mm
MIN_STEPS_PER_MM = 1e-3   # steps/mm: a step of a metre


def _rule_at_least_or_inf(lo: float, unit: str, optional: bool = False) -> Rule:
    def rule(v: Any) -> str | None:
        if optional and v is None:
            return None
        if not is_number(v) or not v >= lo:      # also rejects NaN
            return f"must be at least {lo:g} {unit} (inf = no limit)"
        return None
    return rule


def _rule_steps_per_mm(v: Any) -> str | None:
    if not is_number(v) or not (MIN_STEPS_PER_MM <= v <= MAX_STEPS_PER_MM):
        return "must be a number of steps/mm from 0.001 (a step of 1 m) to 1e6 (a step of 1 nm)"
    return None


def _rule_speed_at_least(lo: float) -> Rule:
    def rule(v: Any) -> str | None:
        if not is_number(v) or not (v >= lo and math.isfinite(v)):
            return f"must be a finite speed of at least {lo:g} mm/s"
        return None
    return rule


def _rule_positive(v: Any) -> str | None:
    if not is_number(v) or not (v > 0 and math.isfinite(v)):
        return "must be a positive finite number"
    return None


def _rule_non_negative(v: Any) -> str | None:
    if not is_number(v) or not (v >= 0 and math.isfinite(v)):
        return "must be a finite number >= 0"
    return None


def _rule_zero_or_one(v: Any) -> str | None:
    if not is_number(v) or v not in (0, 1):
        return "must be 0 or 1"
    return None


def rule_block_buffer(v: Any) -> str | None:
    """Marlin's BLOCK_BUFFER_SIZE (machine ``marlin_block_buffer``, Configuration_adv.h): what is wrong with ``v``,
    or None."""
    if not is_number(v) or not (v >= 2 and v == int(v) and int(v) & (int(v) - 1) == 0 and v <= 1024):
        return "must be a power of 2 from 2 to 1024 (Marlin builds only with a power of 2: SanityCheck.h)"
    return None


def _rule_non_negative_or_inf(v: Any) -> str | None:
    if not is_number(v) or not v >= 0:
        return "must be a number >= 0 (inf = no limit)"
    return None


def _rule_finite(v: Any) -> str | None:
    if not is_number(v) or not math.isfinite(v):
        return "must be a finite number"
    return None


def _rule_number_or_inf(v: Any) -> str | None:
    if not is_number(v) or math.isnan(v):
        return "must be a number (-inf / inf = no limit)"
    return None


def _rule_ratio01(v: Any) -> str | None:
    if not is_number(v) or not (0 <= v < 1):
        return "must be a number in [0, 1)"
    return None


def _rule_optional_positive_or_inf(v: Any) -> str | None:
    return None if v is None else rule_positive_or_inf(v)


def rule_choice(allowed: tuple[str, ...], unsupported: dict[str, str] | None = None) -> Rule:
    def rule(v: Any) -> str | None:
        if not isinstance(v, str):
            return "must be a string: one of " + ", ".join(allowed)
        if v in allowed:
            return None
        if unsupported and v in unsupported:
            return f"{unsupported[v]} (supported: {', '.join(allowed)})"
        # a value that differs only in case ('coreXY') means that value, not the nearest spelling
        close = [a for a in allowed if a.lower() == v.lower()] or difflib.get_close_matches(v, allowed, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return f"unknown value {v!r}: must be one of {', '.join(allowed)}{hint}"
    return rule


def _rule_kinematics(v: Any) -> str | None:
    """A built-in kinematics or one registered with gcodeplan.kinematics.register (a --plugin file's)."""
    if isinstance(v, str) and v not in KINEMATICS:
        from ..kinematics.plugin import _REGISTRY

        if v in _REGISTRY:
            return None
    return rule_choice(KINEMATICS, UNSUPPORTED_KINEMATICS)(v)


def _rule_smooth_time(v: Any) -> str | None:
    # Klipper's extruder.py: pressure_advance_smooth_time above 0, at most 0.2 s
    if not is_number(v) or not (0.0 < v <= 0.2):
        return "must be a time in (0, 0.2] s"
    return None


def _rule_macros(v: Any) -> str | None:
    # [time] macros = { PRINT_START = 240 }: command name -> seconds (gcode/interp.py times them as waits)
    if not isinstance(v, dict):
        return "must be a table of command name = seconds"
    for k, t in v.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.]*", str(k)):
            return f"{k!r} is not a command name"
        if not is_number(t) or not (t >= 0 and math.isfinite(t)):
            return f"{k}: must be a finite number of seconds >= 0"
    return None


def _rule_string(v: Any) -> str | None:
    return None if isinstance(v, str) else "must be a string"


def _rule_triple(inner: Rule) -> Rule:
    """One value per delta tower (a, b, c): three numbers, each passing ``inner``."""
    def rule(v: Any) -> str | None:
        if not isinstance(v, tuple) or len(v) != 3:
            return "must be a number or an array of three numbers (towers a, b, c)"
        for x in v:
            problem = inner(x)
            if problem is not None:
                return problem + " (each tower)"
        return None
    return rule


@dataclass(frozen=True)
class Field:
    section: str      # "" = top level; "axis" = every [axis.<a>] table
    key: str          # TOML key
    attr: str         # Machine (or Axis, for section "axis") attribute
    rule: Rule
    kind: str         # "number", "string": the TOML type expected
    unit: str         # for messages and docs


_SPEED = _rule_at_least_or_inf(MIN_SPEED, "mm/s")
_OPT_SPEED = _rule_at_least_or_inf(MIN_SPEED, "mm/s", optional=True)
_ACCEL = _rule_at_least_or_inf(MIN_ACCEL, "mm/s²")
_OPT_ACCEL = _rule_at_least_or_inf(MIN_ACCEL, "mm/s²", optional=True)
_JERK = _rule_at_least_or_inf(MIN_ACCEL, "mm/s³")

FIELDS: tuple[Field, ...] = (
    Field("", "name", "name", _rule_string, "string", ""),
    Field("", "kinematics", "kinematics", lambda v: _rule_kinematics(v), "string", ""),
    Field("", "flavor", "flavor", rule_choice(FLAVORS), "string", ""),
    Field("", "firmware", "firmware", rule_choice(FIRMWARES), "string", ""),
    Field("", "grbl_idle_lock_ms", "grbl_idle_lock_ms", _rule_non_negative, "number", "ms"),
    Field("", "marlin_build", "marlin_build", lambda v: rule_marlin_build(v), "string", ""),
    Field("", "grbl_laser_mode", "grbl_laser_mode", _rule_zero_or_one, "number", ""),
    Field("", "marlin_block_buffer", "marlin_block_buffer", rule_block_buffer, "number", "blocks"),
    Field("", "acceleration_profile", "acceleration_profile", rule_choice(ACCELERATION_PROFILES), "string", ""),
    Field("toolhead", "max_velocity", "max_velocity", _SPEED, "number", "mm/s"),
    Field("toolhead", "max_accel", "max_accel", _ACCEL, "number", "mm/s²"),
    Field("toolhead", "accel_print", "accel_print", _OPT_ACCEL, "number", "mm/s²"),
    Field("toolhead", "accel_travel", "accel_travel", _OPT_ACCEL, "number", "mm/s²"),
    Field("toolhead", "accel_retract", "accel_retract", _OPT_ACCEL, "number", "mm/s²"),
    Field("toolhead", "rapid_velocity", "rapid_velocity", _OPT_SPEED, "number", "mm/s"),
    Field("junction", "policy", "junction_policy", rule_choice(POLICIES), "string", ""),
    Field("junction", "square_corner_velocity", "square_corner_velocity", _rule_non_negative, "number", "mm/s"),
    Field("junction", "minimum_cruise_ratio", "minimum_cruise_ratio", _rule_ratio01, "number", ""),
    Field("junction", "junction_deviation", "junction_deviation", _rule_non_negative, "number", "mm"),
    Field("junction", "blend_tolerance", "blend_tolerance", _rule_non_negative, "number", "mm"),
    Field("junction", "max_jerk", "max_jerk", _JERK, "number", "mm/s³"),
    Field("axis", "max_velocity", "max_velocity", _SPEED, "number", "mm/s"),
    Field("axis", "max_accel", "max_accel", _ACCEL, "number", "mm/s²"),
    Field("axis", "jerk", "jerk", _rule_non_negative_or_inf, "number", "mm/s"),
    Field("axis", "steps_per_mm", "steps_per_mm", _rule_steps_per_mm, "number", "steps/mm"),
    Field("axis", "home", "home", _rule_finite, "number", "mm"),
    Field("axis", "position_min", "position_min", _rule_number_or_inf, "number", "mm"),
    Field("axis", "position_max", "position_max", _rule_number_or_inf, "number", "mm"),
    Field("extruder", "nozzle_diameter", "nozzle_diameter", _rule_positive, "number", "mm"),
    Field("extruder", "filament_diameter", "filament_diameter", _rule_positive, "number", "mm"),
    Field("extruder", "max_extrude_only_velocity", "max_extrude_only_velocity", _SPEED,
           "number", "mm/s"),
    Field("extruder", "max_extrude_only_accel", "max_extrude_only_accel", _ACCEL,
           "number", "mm/s²"),
    Field("extruder", "instantaneous_corner_velocity", "instantaneous_corner_velocity", _rule_non_negative,
           "number", "mm/s"),
    Field("extruder", "max_extrude_ratio", "max_extrude_ratio", rule_positive_or_inf, "number", ""),
    Field("arcs", "tolerance", "arc_tolerance", _rule_positive, "number", "mm"),
    Field("arcs", "resolution", "arc_resolution", _rule_non_negative, "number", "mm"),
    Field("firmware_retraction", "retract_length", "retract_length", _rule_non_negative, "number", "mm"),
    Field("firmware_retraction", "retract_speed", "retract_speed", _rule_speed_at_least(MIN_SPEED), "number", "mm/s"),
    Field("firmware_retraction", "unretract_extra_length", "unretract_extra_length", _rule_non_negative,
           "number", "mm"),
    Field("firmware_retraction", "unretract_speed", "unretract_speed", _rule_speed_at_least(MIN_SPEED), "number", "mm/s"),
    Field("time", "homing_time", "homing_time", _rule_non_negative, "number", "s"),
    Field("time", "heat_wait_time", "heat_wait_time", _rule_non_negative, "number", "s"),
    Field("time", "tool_change_time", "tool_change_time", _rule_non_negative, "number", "s"),
    Field("time", "filament_change_time", "filament_change_time", _rule_non_negative, "number", "s"),
    Field("time", "start_time", "start_time", _rule_non_negative, "number", "s"),
    Field("time", "macros", "macros", lambda v: _rule_macros(v), "table", "s"),
    Field("stepper", "max_step_rate", "max_step_rate", rule_positive_or_inf, "number", "steps/s"),
    # step stream only (the planned times do not change): Klipper's pressure advance and input shaper
    Field("extruder", "pressure_advance", "pressure_advance", _rule_non_negative, "number", "s"),
    Field("extruder", "pressure_advance_smooth_time", "pressure_advance_smooth_time", _rule_smooth_time,
           "number", "s"),
    Field("input_shaper", "shaper_type_x", "shaper_type_x", rule_choice(SHAPER_TYPES[1:]), "string", ""),
    Field("input_shaper", "shaper_type_y", "shaper_type_y", rule_choice(SHAPER_TYPES[1:]), "string", ""),
    Field("input_shaper", "shaper_freq_x", "shaper_freq_x", _rule_non_negative, "number", "Hz"),
    Field("input_shaper", "shaper_freq_y", "shaper_freq_y", _rule_non_negative, "number", "Hz"),
    Field("input_shaper", "damping_ratio_x", "damping_ratio_x", _rule_ratio01, "number", ""),
    Field("input_shaper", "damping_ratio_y", "damping_ratio_y", _rule_ratio01, "number", ""),
    # linear delta (kinematics = "delta"): Klipper's [printer] delta_radius … and [stepper_a|b|c]
    Field("delta", "radius", "delta_radius", _rule_non_negative, "number", "mm"),
    Field("delta", "print_radius", "print_radius", _rule_optional_positive_or_inf, "number", "mm"),
    Field("delta", "minimum_z_position", "minimum_z_position", _rule_finite, "number", "mm"),
    Field("delta", "arm_length", "delta_arm_length", _rule_triple(_rule_non_negative), "triple", "mm"),
    Field("delta", "angle", "delta_angle", _rule_triple(_rule_finite), "triple", "°"),
    Field("delta", "position_endstop", "delta_position_endstop", _rule_triple(_rule_finite), "triple", "mm"),
    Field("delta", "steps_per_mm", "delta_steps_per_mm", _rule_triple(_rule_steps_per_mm), "triple", "steps/mm"),
)

# Keys that are read but are not Machine fields: they are turned into one.
AXIS_STEP_KEYS = ("rotation_distance", "microsteps", "full_steps_per_rotation", "gear_ratio")
EXTRUDER_EXTRA_KEYS = ("max_extrude_cross_section",)
TOP_EXTRA_KEYS = ("base",)

SECTIONS = ("toolhead", "junction", "axis", "extruder", "arcs", "firmware_retraction", "time", "stepper",
             "input_shaper", "delta")


def section_keys(section: str) -> list[str]:
    keys = [f.key for f in FIELDS if f.section == section]
    if section == "axis":
        keys += list(AXIS_STEP_KEYS)
    elif section == "extruder":
        keys += list(EXTRUDER_EXTRA_KEYS)
    elif section == "":
        keys += list(TOP_EXTRA_KEYS)
    return keys


def toml_path(f: Field, axis: str | None = None) -> str:
    if f.section == "":
        return f.key
    if f.section == "axis":
        return f"axis.{axis}.{f.key}"
    return f"{f.section}.{f.key}"


def show_value(v: Any) -> str:
    """A value as the user wrote it in TOML, for messages."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return repr(v)
    if isinstance(v, float) and v.is_integer():
        return str(int(v)) if abs(v) < 1e16 else repr(v)
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        return "an array"
    return str(v)


# ============================================================================ validation

def validate(machine: Machine, source: str | None = None) -> None:
    """Check every field of ``machine``; raise ConfigError naming the TOML key of the first bad one.

    ``source`` (a file name) is put in front of the message when given.
    """
    for f in FIELDS:
        if f.section == "axis":
            continue
        _check(f, getattr(machine, f.attr, None), source)
    axes = machine.axes
    if not isinstance(axes, dict) or set(axes) != set(AXES):
        got = sorted(axes) if isinstance(axes, dict) else type(axes).__name__
        raise ConfigError(f"axis: the axes must be exactly {', '.join(AXES)}, got {got}", source)
    for a in AXES:
        ax = axes[a]
        if not isinstance(ax, Axis):
            raise ConfigError(f"axis.{a}: must be an Axis, got {type(ax).__name__}", source)
        for f in FIELDS:
            if f.section == "axis":
                _check(f, getattr(ax, f.attr), source, axis=a)
        # Klipper's stepper.py: position_max must be above position_min.
        if not ax.position_max > ax.position_min:
            raise ConfigError(f"axis.{a}.position_max: must be above position_min ({show_value(ax.position_min)}), "
                              f"got {show_value(ax.position_max)}", source)
    problem = firmware_policy_conflict(machine.firmware, machine.junction_policy)
    if problem is not None:
        raise ConfigError(problem, source)
    # Klipper's corner rule takes δ = scv²·(√2−1)/max_accel and multiplies it back by the accel:
    # with an infinite max_accel that is inf·0, no answer at all.
    if machine.junction_policy == "klipper" and not math.isfinite(machine.max_accel):
        raise ConfigError("toolhead.max_accel: must be finite with junction.policy 'klipper', got inf", source)
    if machine.kinematics == "delta":
        from ..kinematics.delta import check_machine

        try:
            check_machine(machine)
        except ConfigError as err:
            raise ConfigError(err.message, source) from None


def _check(f: Field, value: Any, source: str | None, axis: str | None = None) -> None:
    problem = f.rule(value)
    if problem is not None:
        raise ConfigError(f"{toml_path(f, axis)}: {problem}, got {show_value(value)}", source)


