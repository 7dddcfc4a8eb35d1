"""Machine configuration: gcodeplan's TOML format, Klipper's printer.cfg, presets, validation.

Everything here produces a :class:`gcodeplan.machine.Machine` (the contract; units mm, s, mm/s,
mm/s², mm/s³; ``inf`` = no limit). Every bad value raises :class:`ConfigError` naming the file and
the key (and the line, for printer.cfg), so the CLI prints one line instead of a traceback.

The TOML keys are listed, with units and defaults, in ``docs/machine.md``; the table ``_FIELDS``
below is the single source of truth for them (loader, validation and writer all use it).
"""
from __future__ import annotations

import difflib
import glob as _glob
import math
import os
import re
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any, Callable

from .errors import ConfigError
from .machine import AXES, FLAVORS, KINEMATICS, POLICIES, SHAPER_TYPES, Axis, Machine

__all__ = [
    "load_machine",
    "load_machine_toml",
    "load_klipper_config",
    "machine_from_args",
    "machine_to_toml",
    "preset_names",
    "preset_path",
    "validate",
    "steps_per_mm_from_rotation",
    "parse_gear_ratio",
    "klipper_extrude_ratio",
    "without_bounds",
]

# Kinematics Klipper and others offer that we know about but cannot plan yet.
_UNSUPPORTED_KINEMATICS = {
    "deltesian": "deltesian is not supported yet",
    "rotary_delta": "rotary_delta is not supported yet",
    "polar": "polar is not supported yet",
    "hybrid_corexy": "hybrid_corexy is not supported yet",
    "hybrid_corexz": "hybrid_corexz is not supported yet",
    "winch": "winch is not supported yet",
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


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _rule_positive_or_inf(v: Any) -> str | None:
    if not _is_number(v) or not v > 0:       # also rejects NaN
        return "must be a positive number (inf = no limit)"
    return None


def _rule_positive(v: Any) -> str | None:
    if not _is_number(v) or not (v > 0 and math.isfinite(v)):
        return "must be a positive finite number"
    return None


def _rule_non_negative(v: Any) -> str | None:
    if not _is_number(v) or not (v >= 0 and math.isfinite(v)):
        return "must be a finite number >= 0"
    return None


def _rule_non_negative_or_inf(v: Any) -> str | None:
    if not _is_number(v) or not v >= 0:
        return "must be a number >= 0 (inf = no limit)"
    return None


def _rule_finite(v: Any) -> str | None:
    if not _is_number(v) or not math.isfinite(v):
        return "must be a finite number"
    return None


def _rule_number_or_inf(v: Any) -> str | None:
    if not _is_number(v) or math.isnan(v):
        return "must be a number (-inf / inf = no limit)"
    return None


def _rule_ratio01(v: Any) -> str | None:
    if not _is_number(v) or not (0 <= v < 1):
        return "must be a number in [0, 1)"
    return None


def _rule_optional_positive_or_inf(v: Any) -> str | None:
    return None if v is None else _rule_positive_or_inf(v)


def _rule_choice(allowed: tuple[str, ...], unsupported: dict[str, str] | None = None) -> Rule:
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


def _rule_smooth_time(v: Any) -> str | None:
    # Klipper's extruder.py: pressure_advance_smooth_time above 0, at most 0.2 s
    if not _is_number(v) or not (0.0 < v <= 0.2):
        return "must be a time in (0, 0.2] s"
    return None


def _rule_macros(v: Any) -> str | None:
    # [time] macros = { PRINT_START = 240 }: command name -> seconds (gcode/interp.py times them as waits)
    if not isinstance(v, dict):
        return "must be a table of command name = seconds"
    for k, t in v.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.]*", str(k)):
            return f"{k!r} is not a command name"
        if not _is_number(t) or not (t >= 0 and math.isfinite(t)):
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
class _Field:
    section: str      # "" = top level; "axis" = every [axis.<a>] table
    key: str          # TOML key
    attr: str         # Machine (or Axis, for section "axis") attribute
    rule: Rule
    kind: str         # "number", "string": the TOML type expected
    unit: str         # for messages and docs


_FIELDS: tuple[_Field, ...] = (
    _Field("", "name", "name", _rule_string, "string", ""),
    _Field("", "kinematics", "kinematics", _rule_choice(KINEMATICS, _UNSUPPORTED_KINEMATICS), "string", ""),
    _Field("", "flavor", "flavor", _rule_choice(FLAVORS), "string", ""),
    _Field("toolhead", "max_velocity", "max_velocity", _rule_positive_or_inf, "number", "mm/s"),
    _Field("toolhead", "max_accel", "max_accel", _rule_positive_or_inf, "number", "mm/s²"),
    _Field("toolhead", "accel_print", "accel_print", _rule_optional_positive_or_inf, "number", "mm/s²"),
    _Field("toolhead", "accel_travel", "accel_travel", _rule_optional_positive_or_inf, "number", "mm/s²"),
    _Field("toolhead", "accel_retract", "accel_retract", _rule_optional_positive_or_inf, "number", "mm/s²"),
    _Field("toolhead", "rapid_velocity", "rapid_velocity", _rule_optional_positive_or_inf, "number", "mm/s"),
    _Field("junction", "policy", "junction_policy", _rule_choice(POLICIES), "string", ""),
    _Field("junction", "square_corner_velocity", "square_corner_velocity", _rule_non_negative, "number", "mm/s"),
    _Field("junction", "minimum_cruise_ratio", "minimum_cruise_ratio", _rule_ratio01, "number", ""),
    _Field("junction", "junction_deviation", "junction_deviation", _rule_non_negative, "number", "mm"),
    _Field("junction", "blend_tolerance", "blend_tolerance", _rule_non_negative, "number", "mm"),
    _Field("junction", "max_jerk", "max_jerk", _rule_positive_or_inf, "number", "mm/s³"),
    _Field("axis", "max_velocity", "max_velocity", _rule_positive_or_inf, "number", "mm/s"),
    _Field("axis", "max_accel", "max_accel", _rule_positive_or_inf, "number", "mm/s²"),
    _Field("axis", "jerk", "jerk", _rule_non_negative_or_inf, "number", "mm/s"),
    _Field("axis", "steps_per_mm", "steps_per_mm", _rule_positive, "number", "steps/mm"),
    _Field("axis", "home", "home", _rule_finite, "number", "mm"),
    _Field("axis", "position_min", "position_min", _rule_number_or_inf, "number", "mm"),
    _Field("axis", "position_max", "position_max", _rule_number_or_inf, "number", "mm"),
    _Field("extruder", "nozzle_diameter", "nozzle_diameter", _rule_positive, "number", "mm"),
    _Field("extruder", "filament_diameter", "filament_diameter", _rule_positive, "number", "mm"),
    _Field("extruder", "max_extrude_only_velocity", "max_extrude_only_velocity", _rule_positive_or_inf,
           "number", "mm/s"),
    _Field("extruder", "max_extrude_only_accel", "max_extrude_only_accel", _rule_positive_or_inf,
           "number", "mm/s²"),
    _Field("extruder", "instantaneous_corner_velocity", "instantaneous_corner_velocity", _rule_non_negative,
           "number", "mm/s"),
    _Field("extruder", "max_extrude_ratio", "max_extrude_ratio", _rule_positive_or_inf, "number", ""),
    _Field("arcs", "tolerance", "arc_tolerance", _rule_positive, "number", "mm"),
    _Field("arcs", "resolution", "arc_resolution", _rule_non_negative, "number", "mm"),
    _Field("firmware_retraction", "retract_length", "retract_length", _rule_non_negative, "number", "mm"),
    _Field("firmware_retraction", "retract_speed", "retract_speed", _rule_positive, "number", "mm/s"),
    _Field("firmware_retraction", "unretract_extra_length", "unretract_extra_length", _rule_non_negative,
           "number", "mm"),
    _Field("firmware_retraction", "unretract_speed", "unretract_speed", _rule_positive, "number", "mm/s"),
    _Field("time", "homing_time", "homing_time", _rule_non_negative, "number", "s"),
    _Field("time", "heat_wait_time", "heat_wait_time", _rule_non_negative, "number", "s"),
    _Field("time", "tool_change_time", "tool_change_time", _rule_non_negative, "number", "s"),
    _Field("time", "filament_change_time", "filament_change_time", _rule_non_negative, "number", "s"),
    _Field("time", "start_time", "start_time", _rule_non_negative, "number", "s"),
    _Field("time", "macros", "macros", lambda v: _rule_macros(v), "table", "s"),
    _Field("stepper", "max_step_rate", "max_step_rate", _rule_positive_or_inf, "number", "steps/s"),
    # step stream only (the planned times do not change): Klipper's pressure advance and input shaper
    _Field("extruder", "pressure_advance", "pressure_advance", _rule_non_negative, "number", "s"),
    _Field("extruder", "pressure_advance_smooth_time", "pressure_advance_smooth_time", _rule_smooth_time,
           "number", "s"),
    _Field("input_shaper", "shaper_type_x", "shaper_type_x", _rule_choice(SHAPER_TYPES[1:]), "string", ""),
    _Field("input_shaper", "shaper_type_y", "shaper_type_y", _rule_choice(SHAPER_TYPES[1:]), "string", ""),
    _Field("input_shaper", "shaper_freq_x", "shaper_freq_x", _rule_non_negative, "number", "Hz"),
    _Field("input_shaper", "shaper_freq_y", "shaper_freq_y", _rule_non_negative, "number", "Hz"),
    _Field("input_shaper", "damping_ratio_x", "damping_ratio_x", _rule_ratio01, "number", ""),
    _Field("input_shaper", "damping_ratio_y", "damping_ratio_y", _rule_ratio01, "number", ""),
    # linear delta (kinematics = "delta"): Klipper's [printer] delta_radius … and [stepper_a|b|c]
    _Field("delta", "radius", "delta_radius", _rule_non_negative, "number", "mm"),
    _Field("delta", "print_radius", "print_radius", _rule_optional_positive_or_inf, "number", "mm"),
    _Field("delta", "minimum_z_position", "minimum_z_position", _rule_finite, "number", "mm"),
    _Field("delta", "arm_length", "delta_arm_length", _rule_triple(_rule_non_negative), "triple", "mm"),
    _Field("delta", "angle", "delta_angle", _rule_triple(_rule_finite), "triple", "°"),
    _Field("delta", "position_endstop", "delta_position_endstop", _rule_triple(_rule_finite), "triple", "mm"),
    _Field("delta", "steps_per_mm", "delta_steps_per_mm", _rule_triple(_rule_positive), "triple", "steps/mm"),
)

# Keys that are read but are not Machine fields: they are turned into one.
_AXIS_STEP_KEYS = ("rotation_distance", "microsteps", "full_steps_per_rotation", "gear_ratio")
_EXTRUDER_EXTRA_KEYS = ("max_extrude_cross_section",)
_TOP_EXTRA_KEYS = ("base",)

_SECTIONS = ("toolhead", "junction", "axis", "extruder", "arcs", "firmware_retraction", "time", "stepper",
             "input_shaper", "delta")


def _section_keys(section: str) -> list[str]:
    keys = [f.key for f in _FIELDS if f.section == section]
    if section == "axis":
        keys += list(_AXIS_STEP_KEYS)
    elif section == "extruder":
        keys += list(_EXTRUDER_EXTRA_KEYS)
    elif section == "":
        keys += list(_TOP_EXTRA_KEYS)
    return keys


def _toml_path(f: _Field, axis: str | None = None) -> str:
    if f.section == "":
        return f.key
    if f.section == "axis":
        return f"axis.{axis}.{f.key}"
    return f"{f.section}.{f.key}"


def _show(v: Any) -> str:
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
    for f in _FIELDS:
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
        for f in _FIELDS:
            if f.section == "axis":
                _check(f, getattr(ax, f.attr), source, axis=a)
        # Klipper's stepper.py: position_max must be above position_min.
        if not ax.position_max > ax.position_min:
            raise ConfigError(f"axis.{a}.position_max: must be above position_min ({_show(ax.position_min)}), "
                              f"got {_show(ax.position_max)}", source)
    # Klipper's corner rule takes δ = scv²·(√2−1)/max_accel and multiplies it back by the accel:
    # with an infinite max_accel that is inf·0, no answer at all.
    if machine.junction_policy == "klipper" and not math.isfinite(machine.max_accel):
        raise ConfigError("toolhead.max_accel: must be finite with junction.policy 'klipper', got inf", source)
    if machine.kinematics == "delta":
        from .kinematics.delta import check_machine

        try:
            check_machine(machine)
        except ConfigError as err:
            raise ConfigError(err.message, source) from None


def _check(f: _Field, value: Any, source: str | None, axis: str | None = None) -> None:
    problem = f.rule(value)
    if problem is not None:
        raise ConfigError(f"{_toml_path(f, axis)}: {problem}, got {_show(value)}", source)


# ============================================================================ TOML

def preset_names() -> list[str]:
    """Names of the machines shipped in gcodeplan/presets (``load_machine(name)`` reads them)."""
    folder = resources.files("gcodeplan").joinpath("presets")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def preset_path(name: str) -> str:
    """Display name of a preset's file, used in messages (``presets/klipper.toml``)."""
    return f"presets/{name}.toml"


def _preset_text(name: str) -> str:
    return resources.files("gcodeplan").joinpath("presets", f"{name}.toml").read_text(encoding="utf-8")


def load_machine(path_or_preset: str) -> Machine:
    """A machine from a TOML file, or from a preset name (``klipper``, ``marlin``, ``grbl``).

    An existing regular file wins over a preset of the same name; a directory never does.
    """
    spec = str(path_or_preset)
    if spec.endswith(".cfg"):
        if not os.path.exists(spec):
            raise ConfigError("no such file", spec)
        raise ConfigError("this looks like a Klipper printer.cfg: use --klipper-config for it", spec)
    if os.path.isfile(spec):
        return load_machine_toml(spec)
    presets = preset_names()
    if spec in presets:
        return _load_toml_text(_preset_text(spec), preset_path(spec), base_dir=None, seen=(spec,))
    if os.sep in spec or "/" in spec or spec.endswith(".toml") or os.path.exists(spec):
        return load_machine_toml(spec)
    close = difflib.get_close_matches(spec, presets, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ConfigError(f"machine {spec!r} is neither a file nor a preset; presets: {', '.join(presets)}{hint}")


def load_machine_toml(path: str, _seen: tuple[str, ...] = ()) -> Machine:
    """A machine from a gcodeplan TOML file (format: docs/machine.md)."""
    text = _read_text(path)
    return _load_toml_text(text, str(path), base_dir=os.path.dirname(os.path.abspath(path)),
                           seen=_seen + (os.path.abspath(path),))


def _read_text(path: str) -> str:
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise ConfigError("no such file", str(path)) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, not a file", str(path)) from None
    except PermissionError:
        raise ConfigError("permission denied", str(path)) from None
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror or err}", str(path)) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError(f"not a UTF-8 text file (byte {err.start})", str(path)) from None


_TOML_LINE = re.compile(r"\(at line (\d+), column (\d+)\)")


def _load_toml_text(text: str, source: str, base_dir: str | None, seen: tuple[str, ...]) -> Machine:
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        msg = str(err)
        m = _TOML_LINE.search(msg)
        line = int(m.group(1)) if m else None
        msg = _TOML_LINE.sub("", msg).strip()
        if m:
            msg += f" (column {m.group(2)})"
        raise ConfigError(f"TOML syntax error: {msg}", source, line) from None

    machine = _base_machine(doc.get("base"), source, base_dir, seen)
    _apply_toml(doc, machine, source)
    validate(machine, source)
    return machine


def _base_machine(base: Any, source: str, base_dir: str | None, seen: tuple[str, ...]) -> Machine:
    """``base = "marlin"`` (a preset) or ``base = "other.toml"`` (relative to this file): start from it."""
    if base is None:
        return Machine()
    if not isinstance(base, str):
        raise ConfigError(f"base: must be a string (a preset name or a TOML file), got {_show(base)}", source)
    if base in preset_names() and not (base_dir and os.path.isfile(os.path.join(base_dir, base))):
        if base in seen:
            raise ConfigError(f"base: {base!r} includes itself", source)
        return _load_toml_text(_preset_text(base), preset_path(base), None, seen + (base,))
    if base_dir is None:
        raise ConfigError(f"base: unknown preset {base!r}; presets: {', '.join(preset_names())}", source)
    path = os.path.join(base_dir, base)
    if os.path.abspath(path) in seen:
        raise ConfigError(f"base: {base!r} includes itself", source)
    if not os.path.exists(path):
        raise ConfigError(f"base: {base!r} is neither a preset ({', '.join(preset_names())}) "
                          f"nor a file next to this one", source)
    return load_machine_toml(path, seen)


def _unknown(path: str, what: str, candidates: list[str]) -> str:
    name = path.rsplit(".", 1)[-1]
    # A truncated key ("steps") means the key it begins; otherwise the most similar spelling.
    close = sorted((c for c in candidates if c.startswith(name)), key=len) if len(name) >= 3 else []
    close = close or difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{path}: unknown {what}{hint}"


def _apply_toml(doc: dict[str, Any], machine: Machine, source: str) -> None:
    top_keys = _section_keys("")
    for key, value in doc.items():
        if isinstance(value, dict):
            if key not in _SECTIONS:
                raise ConfigError(_unknown(key, "section", list(_SECTIONS)), source)
            if key == "axis":
                _apply_axes(value, machine, source)
            else:
                _apply_section(key, value, machine, source)
        elif key in top_keys:
            if key != "base":
                _set(machine, _field("", key), value, source)
        elif key in _SECTIONS:
            raise ConfigError(f"{key}: must be a table [{key}], got {_show(value)}", source)
        else:
            owners = [s for s in _SECTIONS if key in _section_keys(s)]
            if owners:
                where = "axis.<x|y|z|e>" if owners[0] == "axis" else owners[0]
                raise ConfigError(f"{key}: unknown top-level key (it belongs in [{where}])", source)
            raise ConfigError(_unknown(key, "key", top_keys + list(_SECTIONS)), source)


def _field(section: str, key: str) -> _Field:
    for f in _FIELDS:
        if f.section == section and f.key == key:
            return f
    raise KeyError((section, key))


def _coerce(f: _Field, value: Any, path: str, source: str) -> Any:
    """TOML value → Python value of the field's kind; only type errors here, ranges in the rule."""
    if f.kind == "string":
        if not isinstance(value, str):
            raise ConfigError(f"{path}: must be a string, got {_show(value)}", source)
        return value
    if f.kind == "table":
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: must be a table, got {_show(value)}", source)
        return {str(k): (float(t) if _is_number(t) else t) for k, t in value.items()}
    if f.kind == "triple":
        # one number for the three towers, or [a, b, c]
        vals = value if isinstance(value, list) else [value] * 3
        if len(vals) != 3 or not all(_is_number(x) for x in vals):
            raise ConfigError(f"{path}: must be a number or an array of three numbers (towers a, b, c), "
                              f"got {_show(value)}", source)
        return tuple(float(x) for x in vals)
    if isinstance(value, str) and value.strip().lower() in ("inf", "+inf", "infinity"):
        return math.inf
    if not _is_number(value):
        raise ConfigError(f"{path}: must be a number, got {_show(value)}", source)
    return float(value)


def _set(target: Any, f: _Field, value: Any, source: str, axis: str | None = None) -> None:
    path = _toml_path(f, axis)
    v = _coerce(f, value, path, source)
    problem = f.rule(v)
    if problem is not None:
        raise ConfigError(f"{path}: {problem}, got {_show(value)}", source)
    setattr(target, f.attr, v)


def _apply_section(section: str, table: dict[str, Any], machine: Machine, source: str) -> None:
    known = _section_keys(section)
    for key, value in table.items():
        if key not in known:
            raise ConfigError(_unknown(f"{section}.{key}", "key", known), source)
        if key in _EXTRUDER_EXTRA_KEYS:
            continue
        _set(machine, _field(section, key), value, source)
    if section == "extruder" and "max_extrude_cross_section" in table:
        if "max_extrude_ratio" in table:
            raise ConfigError("extruder.max_extrude_cross_section: give it or max_extrude_ratio, not both",
                              source)
        path = "extruder.max_extrude_cross_section"
        raw = table["max_extrude_cross_section"]
        cross = _coerce(_field("extruder", "max_extrude_ratio"), raw, path, source)
        problem = _rule_positive_or_inf(cross)
        if problem is not None:
            raise ConfigError(f"{path}: {problem}, got {_show(raw)}", source)
        machine.max_extrude_ratio = klipper_extrude_ratio(cross, machine.filament_diameter)


def _apply_axes(table: dict[str, Any], machine: Machine, source: str) -> None:
    known = _section_keys("axis")
    for a, sub in table.items():
        if a not in AXES:
            raise ConfigError(f"axis.{a}: unknown axis (axes are {', '.join(AXES)})", source)
        if not isinstance(sub, dict):
            raise ConfigError(f"axis.{a}: must be a table [axis.{a}], got {_show(sub)}", source)
        ax = machine.axes[a]
        for key, value in sub.items():
            if key not in known:
                raise ConfigError(_unknown(f"axis.{a}.{key}", "key", known), source)
            if key not in _AXIS_STEP_KEYS:
                _set(ax, _field("axis", key), value, source, axis=a)
        if any(k in sub for k in _AXIS_STEP_KEYS):
            ax.steps_per_mm = _steps_from_toml(a, sub, source)


def _steps_from_toml(a: str, sub: dict[str, Any], source: str) -> float:
    p = f"axis.{a}"
    if "steps_per_mm" in sub:
        raise ConfigError(f"{p}.steps_per_mm: give steps_per_mm or rotation_distance (+ microsteps), not both",
                          source)
    if "rotation_distance" not in sub:
        extra = next(k for k in _AXIS_STEP_KEYS if k in sub)
        raise ConfigError(f"{p}.{extra}: needs {p}.rotation_distance", source)
    if "microsteps" not in sub:
        raise ConfigError(f"{p}.microsteps: required with rotation_distance", source)
    rd = sub["rotation_distance"]
    if not _is_number(rd) or not (rd > 0 and math.isfinite(rd)):
        raise ConfigError(f"{p}.rotation_distance: must be a positive finite number, got {_show(rd)}", source)

    def integer(key: str, default: int) -> int:
        v = sub.get(key, default)
        if not _is_number(v) or not math.isfinite(v) or v != int(v) or v < 1:
            raise ConfigError(f"{p}.{key}: must be a positive integer, got {_show(v)}", source)
        return int(v)

    microsteps = integer("microsteps", 16)
    full_steps = integer("full_steps_per_rotation", 200)
    ratio = sub.get("gear_ratio", 1.0)
    if isinstance(ratio, str):
        try:
            ratio = parse_gear_ratio(ratio)
        except ValueError as err:
            raise ConfigError(f"{p}.gear_ratio: {err}", source) from None
    elif not _is_number(ratio) or not (ratio > 0 and math.isfinite(ratio)):
        raise ConfigError(f"{p}.gear_ratio: must be a positive number or 'a:b, c:d', got {_show(ratio)}", source)
    return steps_per_mm_from_rotation(float(rd), microsteps, full_steps, float(ratio))


# ---------------------------------------------------------------------------- writer

def machine_to_toml(machine: Machine) -> str:
    """The machine in gcodeplan's TOML format; ``load_machine`` of the text gives an equal Machine.

    Written with tomli-w, which escapes every string TOML can hold (tabs, newlines, control
    characters, quotes) and spells ±inf the TOML way."""
    import tomli_w

    validate(machine)
    doc: dict[str, Any] = {}
    for f in _FIELDS:
        if f.section == "axis":
            continue
        value = getattr(machine, f.attr)
        if value is None:
            continue     # None = "use max_accel / max_velocity": omitting the key keeps it
        table = doc if f.section == "" else doc.setdefault(f.section, {})
        if f.kind == "table":
            if value:
                table[f.key] = {k: float(t) for k, t in value.items()}
            continue
        if f.kind == "triple":
            table[f.key] = [float(x) for x in value]
            continue
        table[f.key] = float(value) if f.kind == "number" else value
    doc["axis"] = {a: {f.key: float(getattr(machine.axes[a], f.attr)) for f in _FIELDS if f.section == "axis"}
                   for a in AXES}
    return tomli_w.dumps(doc)


# ============================================================================ Klipper printer.cfg

_AUTOSAVE_MARK = re.compile(r"^#\*#\s*<-+\s*SAVE_CONFIG\s*-+>\s*$")
# Klipper's configfile.py finds the auto-saved block by this exact text (AUTOSAVE_HEADER).
_AUTOSAVE_HEADER = ("\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
                    "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n")
# configparser's section header (RawConfigParser.SECTCRE): greedy, name not stripped.
_SECTION_RE = re.compile(r"\[(?P<name>.+)\]")
# An option line: the key ends at the first ':' or '=' (configparser's OPTCRE).
_OPTION_SEP = re.compile(r"[:=]")


def _cfg_lines(text: str) -> list[str]:
    """Lines the way Klipper splits a config: CR LF → LF, then on LF only (a lone CR stays in its line)."""
    return text.replace("\r\n", "\n").split("\n")


def _strip_cfg_comment(line: str) -> tuple[str, bool]:
    """(line without its comment, whether a ';' comment was cut), as Klipper reads it.

    Klipper's configfile.py cuts every line at the first '#', wherever it is (``max_velocity: 300#fast``
    is 300); then RawConfigParser(inline_comment_prefixes=(';', '#')) cuts at a ';' that starts the
    line or follows whitespace (``300;fast`` stays "300;fast", which is not a number), and drops a
    line whose first non-blank character is ';'.
    """
    cut = line.find("#")
    if cut >= 0:
        line = line[:cut]
    if line.lstrip().startswith(";"):
        return "", True
    start = 0
    while True:
        k = line.find(";", start)
        if k < 0:
            return line, False
        if k == 0 or line[k - 1].isspace():
            return line[:k], True
        start = k + 1


@dataclass
class _CfgValue:
    text: str
    file: str
    line: int


class _KlipperCfg:
    """The sections of a printer.cfg after includes and the SAVE_CONFIG block, with each value's origin.

    Reads what Klipper's configfile.py reads (its ConfigFileReader over a RawConfigParser with
    ``strict=False``, ``inline_comment_prefixes=(';', '#')``; tests/test_config_fidelity.py compares the
    two): section names as written (case-sensitive, not stripped), keys lower-cased, later values win,
    multi-line values joined with newlines, includes relative to the including file and sorted, and
    a SAVE_CONFIG value used only where the regular config (includes too) does not set that key.
    Where Klipper would silently drop the whole SAVE_CONFIG block (a damaged block) this is an error.
    """

    def __init__(self, main: str):
        self.main = main
        self.sections: dict[str, dict[str, _CfgValue]] = {}

    # -- reading
    def read(self) -> "_KlipperCfg":
        text = _read_text(self.main).replace("\r\n", "\n")
        regular, autosave = self._split_autosave(text)
        visiting = (os.path.abspath(self.main),)
        self._parse(list(enumerate(_cfg_lines(regular), start=1)), self.main, visiting)
        saved = _KlipperCfg(self.main)
        saved._parse(autosave, self.main, visiting, allow_include=False)
        # configfile.py _strip_duplicates: an auto-saved key the regular config also sets is commented
        # out, so the user's own line wins (SAVE_CONFIG itself comments out the regular one it replaces).
        for section, values in saved.sections.items():
            target = self.sections.setdefault(section, {})
            for key, value in values.items():
                target.setdefault(key, value)
        for values in self.sections.values():
            for value in values.values():
                value.text = value.text.rstrip()     # configparser: trailing blank lines of a value go
        return self

    def _split_autosave(self, text: str) -> tuple[str, list[tuple[int, str]]]:
        """(regular text, numbered lines of the SAVE_CONFIG block without their '#*# ' prefix)."""
        pos = text.find(_AUTOSAVE_HEADER)
        if pos < 0:
            lines = _cfg_lines(text)
            for n, raw in enumerate(lines, start=1):
                if _AUTOSAVE_MARK.match(raw.strip()):
                    for k, after in enumerate(lines[n:], start=n + 1):
                        if after.strip() and not after.startswith("#*#"):
                            raise ConfigError("a line after the SAVE_CONFIG marker must start with '#*#' "
                                              "(Klipper ignores the whole block otherwise)", self.main, k)
                    raise ConfigError("the SAVE_CONFIG block does not start with Klipper's exact three header "
                                      "lines, so Klipper ignores the whole block", self.main, n)
            return text, []
        regular = text[:pos]
        first = regular.count("\n") + 5            # the header's three lines follow the last regular line
        if "\n#*# " in regular:
            n = regular[:regular.index("\n#*# ") + 1].count("\n") + 1
            raise ConfigError("a '#*#' line before the SAVE_CONFIG block: Klipper ignores the whole block",
                              self.main, n)
        body = text[pos + len(_AUTOSAVE_HEADER):]
        lines = _cfg_lines(body)
        skip = 0
        while skip < len(lines) and not lines[skip].strip():
            skip += 1
        end = len(lines)
        while end > skip and not lines[end - 1].strip():
            end -= 1
        out = []
        for n, raw in enumerate(lines[skip:end], start=first + skip):
            if skip == 0 and n == first:
                raw = raw.lstrip()                   # configfile.py strips the block as a whole
            if not raw.startswith("#*#") or (len(raw) >= 4 and not raw.startswith("#*# ")):
                raise ConfigError("a line after the SAVE_CONFIG marker must start with '#*#' "
                                  "(Klipper ignores the whole block otherwise)", self.main, n)
            out.append((n, raw[4:]))
        return regular, out

    def _parse(self, lines: list[tuple[int, str]], file: str, visiting: tuple[str, ...],
               allow_include: bool = True) -> None:
        section: str | None = None
        key: str | None = None
        key_indent = 0
        for n, raw in lines:
            line, had_comment = _strip_cfg_comment(raw)
            content = line.strip()
            if not content:
                # configparser keeps a blank line inside a multi-line value (empty_lines_in_values)
                if not had_comment and key is not None and section is not None:
                    self.sections[section][key].text += "\n"
                continue
            indent = len(line) - len(line.lstrip())
            if indent > key_indent and key is not None and section is not None:
                prev = self.sections[section][key]
                prev.text = prev.text + "\n" + content      # configparser keeps an empty first line too
                continue
            # Klipper takes a header at column 0 as an include before configparser sees the text.
            mi = _SECTION_RE.match(line)
            if allow_include and mi and mi.group("name").startswith("include "):
                key = None
                self._include(mi.group("name")[len("include "):].strip(), file, n, visiting)
                section = None       # keys after an include need their own [section]
                continue
            ms = _SECTION_RE.match(content)
            if ms:
                section = ms.group("name")
                key = None
                if section == "DEFAULT":
                    raise ConfigError("[DEFAULT]: configparser copies its keys into every section; "
                                      "gcodeplan does not read it", file, n)
                self.sections.setdefault(section, {})
                continue
            if section is None:
                raise ConfigError(f"'{content}' is outside any [section]", file, n)
            sep = _OPTION_SEP.search(content)
            if sep is None or not content[:sep.start()].strip():
                raise ConfigError(f"[{section}]: expected 'key: value', got {content!r}", file, n)
            key = content[:sep.start()].strip().lower()
            key_indent = indent
            self.sections[section][key] = _CfgValue(content[sep.end():].strip(), file, n)

    def _include(self, pattern: str, file: str, line: int, visiting: tuple[str, ...]) -> None:
        if not pattern:
            raise ConfigError("[include]: no file named", file, line)
        # Relative to the including file; paths stay in the form the user gave (for messages).
        matches = sorted(_glob.glob(os.path.join(os.path.dirname(file), pattern)))
        if not matches and not _glob.has_magic(pattern):
            raise ConfigError(f"[include {pattern}]: no such file", file, line)
        for path in matches:
            absolute = os.path.abspath(path)
            if absolute in visiting:
                raise ConfigError(f"[include {pattern}]: recursive include of {path}", file, line)
            text = _read_text(path)
            self._parse(list(enumerate(_cfg_lines(text), start=1)), path, visiting + (absolute,))

    # -- typed access, Klipper's checks (configfile.py getfloat: above / minval / below / maxval)
    def has(self, section: str) -> bool:
        return section in self.sections

    def raw(self, section: str, key: str) -> _CfgValue | None:
        return self.sections.get(section, {}).get(key)

    def get_float(self, section: str, key: str, default: float | None = None, *, required: bool = False,
                  above: float | None = None, minval: float | None = None,
                  below: float | None = None, maxval: float | None = None) -> float | None:
        v = self.raw(section, key)
        if v is None:
            if required:
                raise ConfigError(f"[{section}] {key} is required", self.main)
            return default
        where = f"[{section}] {key}"
        try:
            x = float(v.text)
        except ValueError:
            raise ConfigError(f"{where}: not a number: {v.text!r}", v.file, v.line) from None
        if not math.isfinite(x):
            raise ConfigError(f"{where}: must be a finite number, got {v.text!r}", v.file, v.line)
        if above is not None and not x > above:
            raise ConfigError(f"{where}: must be above {above:g}, got {v.text}", v.file, v.line)
        if minval is not None and not x >= minval:
            raise ConfigError(f"{where}: must be at least {minval:g}, got {v.text}", v.file, v.line)
        if below is not None and not x < below:
            raise ConfigError(f"{where}: must be below {below:g}, got {v.text}", v.file, v.line)
        if maxval is not None and not x <= maxval:
            raise ConfigError(f"{where}: must be at most {maxval:g}, got {v.text}", v.file, v.line)
        return x

    def get_int(self, section: str, key: str, default: int | None = None, *, required: bool = False,
                minval: int | None = None) -> int | None:
        v = self.raw(section, key)
        if v is None:
            if required:
                raise ConfigError(f"[{section}] {key} is required", self.main)
            return default
        try:
            x = int(v.text)
        except ValueError:
            raise ConfigError(f"[{section}] {key}: not an integer: {v.text!r}", v.file, v.line) from None
        if minval is not None and x < minval:
            raise ConfigError(f"[{section}] {key}: must be at least {minval}, got {v.text}", v.file, v.line)
        return x


def _klipper_travel_limits(cfg: _KlipperCfg, section: str, axis: Axis) -> None:
    """stepper.py PrinterRail: position_min (default 0) < position_max, position_endstop between them (mm).

    Klipper requires position_max; a config without it is read here with no limit on that axis (only
    position_min, when given, bounds it below)."""
    has_max = cfg.raw(section, "position_max") is not None
    lo = cfg.get_float(section, "position_min", 0.0 if has_max else -math.inf)
    if not has_max:
        axis.position_min = lo
        return
    hi = cfg.get_float(section, "position_max", required=True, above=lo)
    if not lo <= axis.home <= hi:
        v = cfg.raw(section, "position_endstop") or cfg.raw(section, "position_max")
        raise ConfigError(f"position_endstop in section '{section}' must be between position_min and "
                          f"position_max", v.file, v.line)
    axis.position_min, axis.position_max = lo, hi


def _klipper_steps_per_mm(cfg: _KlipperCfg, section: str) -> float:
    """Klipper stepper.py: step_distance = rotation_distance / (full_steps · microsteps · gear_ratio)."""
    rotation_distance = cfg.get_float(section, "rotation_distance", required=True, above=0.0)
    microsteps = cfg.get_int(section, "microsteps", required=True, minval=1)
    full_steps = cfg.get_int(section, "full_steps_per_rotation", 200, minval=1)
    if full_steps % 4:
        v = cfg.raw(section, "full_steps_per_rotation")
        raise ConfigError(f"[{section}] full_steps_per_rotation: must be a multiple of 4, got {full_steps}",
                          v.file, v.line)
    ratio = 1.0
    v = cfg.raw(section, "gear_ratio")
    if v is not None and v.text.strip():
        try:
            ratio = parse_gear_ratio(v.text)
        except ValueError as err:
            raise ConfigError(f"[{section}] gear_ratio: {err}", v.file, v.line) from None
    return steps_per_mm_from_rotation(rotation_distance, microsteps, full_steps, ratio)


def load_klipper_config(path: str) -> Machine:
    """A machine from a Klipper printer.cfg: flavor and junction policy "klipper".

    Reads [printer], [stepper_x|y|z], [extruder], [gcode_arcs], [firmware_retraction] with Klipper's
    defaults and range checks; other sections and keys are ignored (they do not change planned times).
    """
    cfg = _KlipperCfg(str(path)).read()
    if not cfg.has("printer"):
        raise ConfigError("[printer] section is required", cfg.main)

    kin_value = cfg.raw("printer", "kinematics")
    if kin_value is None:
        raise ConfigError("[printer] kinematics is required", cfg.main)
    kinematics = kin_value.text.strip().lower()
    if kinematics not in KINEMATICS:
        reason = _UNSUPPORTED_KINEMATICS.get(kinematics, f"kinematics {kinematics!r} is not supported")
        raise ConfigError(f"[printer] kinematics: {reason} (supported: {', '.join(KINEMATICS)})",
                          kin_value.file, kin_value.line)

    m = Machine(name=Path(path).stem, kinematics=kinematics, flavor="klipper", junction_policy="klipper")
    m.max_velocity = cfg.get_float("printer", "max_velocity", required=True, above=0.0)
    m.max_accel = cfg.get_float("printer", "max_accel", required=True, above=0.0)
    # toolhead.py: the older max_accel_to_decel maps to mcr = 1 − min(1, a2d/max_accel);
    # an explicit minimum_cruise_ratio wins over it.
    mcr_default = 0.5
    a2d = cfg.get_float("printer", "max_accel_to_decel", None, above=0.0)
    if a2d is not None:
        mcr_default = 1.0 - min(1.0, a2d / m.max_accel)
    m.minimum_cruise_ratio = cfg.get_float("printer", "minimum_cruise_ratio", mcr_default, minval=0.0, below=1.0)
    m.square_corner_velocity = cfg.get_float("printer", "square_corner_velocity", 5.0, minval=0.0)

    if kinematics == "delta":
        _klipper_delta(cfg, m)
    for a in ("x", "y", "z") if kinematics != "delta" else ():
        section = f"stepper_{a}"
        if not cfg.has(section):
            raise ConfigError(f"[{section}] section is required", cfg.main)
        m.axes[a].steps_per_mm = _klipper_steps_per_mm(cfg, section)
        m.axes[a].home = cfg.get_float(section, "position_endstop", 0.0)
        _klipper_travel_limits(cfg, section, m.axes[a])
    # cartesian.py / corexy.py: only Z has limits of its own; X/Y stay unlimited (inf).
    m.axes["z"].max_velocity = cfg.get_float("printer", "max_z_velocity", m.max_velocity,
                                             above=0.0, maxval=m.max_velocity)
    m.axes["z"].max_accel = cfg.get_float("printer", "max_z_accel", m.max_accel, above=0.0, maxval=m.max_accel)

    if cfg.has("extruder"):
        _klipper_extruder(cfg, m)
    if cfg.has("input_shaper"):
        _klipper_input_shaper(cfg, m)
    if cfg.has("gcode_arcs"):
        m.arc_resolution = cfg.get_float("gcode_arcs", "resolution", 1.0, above=0.0)
    if cfg.has("firmware_retraction"):
        s = "firmware_retraction"
        m.retract_length = cfg.get_float(s, "retract_length", 0.0, minval=0.0)
        m.retract_speed = cfg.get_float(s, "retract_speed", 20.0, minval=1.0)
        m.unretract_extra_length = cfg.get_float(s, "unretract_extra_length", 0.0, minval=0.0)
        m.unretract_speed = cfg.get_float(s, "unretract_speed", 10.0, minval=1.0)
    validate(m, cfg.main)
    return m


def _klipper_delta(cfg: _KlipperCfg, m: Machine) -> None:
    """kinematics/delta.py: towers [stepper_a|b|c] (steps, position_endstop and arm_length default to
    stepper_a's, angles 210/330/90), [printer] delta_radius, print_radius, minimum_z_position. G28 goes to
    the home position (the carriages at their endstops)."""
    for t in "abc":
        if not cfg.has(f"stepper_{t}"):
            raise ConfigError(f"[stepper_{t}] section is required (kinematics: delta)", cfg.main)
    m.delta_steps_per_mm = tuple(_klipper_steps_per_mm(cfg, f"stepper_{t}") for t in "abc")
    end_a = cfg.get_float("stepper_a", "position_endstop", required=True)
    m.delta_position_endstop = (end_a,) + tuple(cfg.get_float(f"stepper_{t}", "position_endstop", end_a)
                                                for t in "bc")
    m.delta_radius = cfg.get_float("printer", "delta_radius", required=True, above=0.0)
    m.print_radius = cfg.get_float("printer", "print_radius", m.delta_radius, above=0.0)
    arm_a = cfg.get_float("stepper_a", "arm_length", required=True, above=m.delta_radius)
    m.delta_arm_length = (arm_a,) + tuple(cfg.get_float(f"stepper_{t}", "arm_length", arm_a, above=m.delta_radius)
                                          for t in "bc")
    m.delta_angle = tuple(cfg.get_float(f"stepper_{t}", "angle", a) for t, a in zip("abc", (210.0, 330.0, 90.0)))
    m.minimum_z_position = cfg.get_float("printer", "minimum_z_position", 0.0, maxval=min(m.delta_position_endstop))
    from .kinematics.delta import DeltaGeometry

    home = DeltaGeometry.from_machine(m).home_position
    for a, h in zip("xyz", home):
        m.axes[a].home = h


def _klipper_extruder(cfg: _KlipperCfg, m: Machine) -> None:
    """kinematics/extruder.py: step distance, extrude-only limits, corner velocity, max extrude ratio."""
    s = "extruder"
    # Newer Klipper allows an [extruder] without a stepper (one is attached later with
    # SYNC_EXTRUDER_MOTION): then the E step rate is unknown and the default stays.
    if any(cfg.raw(s, k) is not None for k in ("step_pin", "rotation_distance", "microsteps")):
        m.axes["e"].steps_per_mm = _klipper_steps_per_mm(cfg, s)
    m.nozzle_diameter = cfg.get_float(s, "nozzle_diameter", required=True, above=0.0)
    m.filament_diameter = cfg.get_float(s, "filament_diameter", required=True, minval=m.nozzle_diameter)
    default_cross_section = 4.0 * m.nozzle_diameter ** 2
    default_ratio = klipper_extrude_ratio(default_cross_section, m.filament_diameter)
    m.max_extrude_only_velocity = cfg.get_float(s, "max_extrude_only_velocity", m.max_velocity * default_ratio,
                                                above=0.0)
    m.max_extrude_only_accel = cfg.get_float(s, "max_extrude_only_accel", m.max_accel * default_ratio, above=0.0)
    m.instantaneous_corner_velocity = cfg.get_float(s, "instantaneous_corner_velocity", 1.0, minval=0.0)
    cross_section = cfg.get_float(s, "max_extrude_cross_section", default_cross_section, above=0.0)
    m.max_extrude_ratio = klipper_extrude_ratio(cross_section, m.filament_diameter)
    # kinematics/extruder.py: pressure advance (step stream only)
    m.pressure_advance = cfg.get_float(s, "pressure_advance", 0.0, minval=0.0)
    m.pressure_advance_smooth_time = cfg.get_float(s, "pressure_advance_smooth_time", 0.040, above=0.0,
                                                   maxval=0.200)


def _klipper_input_shaper(cfg: _KlipperCfg, m: Machine) -> None:
    """extras/input_shaper.py: shaper_type (both axes) or shaper_type_x/_y, shaper_freq_x/_y, damping_ratio_x/_y."""
    s = "input_shaper"

    def shaper_type(key: str, default: str) -> str:
        v = cfg.raw(s, key)
        if v is None:
            return default
        name = v.text.strip().lower()
        if name not in SHAPER_TYPES[1:]:
            raise ConfigError(f"[{s}] {key}: shaper {name!r} is not modelled (known: {', '.join(SHAPER_TYPES[1:])})",
                              v.file, v.line)
        return name

    both = shaper_type("shaper_type", "mzv")
    for a in ("x", "y"):
        setattr(m, f"shaper_type_{a}", shaper_type(f"shaper_type_{a}", both))
        setattr(m, f"shaper_freq_{a}", cfg.get_float(s, f"shaper_freq_{a}", 0.0, minval=0.0))
        setattr(m, f"damping_ratio_{a}", cfg.get_float(s, f"damping_ratio_{a}", 0.1, minval=0.0, maxval=1.0))
    # Klipper's custom shapers and a Z shaper change the steps too: refuse rather than ignore
    for key in ("shaper_freq_z", "shaper_a_x", "shaper_a_y", "shaper_t_x", "shaper_t_y", "shaper_a_z", "shaper_t_z"):
        v = cfg.raw(s, key)
        if v is not None and not (key == "shaper_freq_z" and _is_zero(v.text)):
            raise ConfigError(f"[{s}] {key}: not modelled (gcodeplan shapes X and Y with Klipper's named "
                              f"shapers only)", v.file, v.line)


def _is_zero(text: str) -> bool:
    try:
        return float(text) == 0.0
    except ValueError:
        return False


# ============================================================================ CLI

def machine_from_args(args: Any) -> Machine:
    """The machine a command runs with: ``--machine`` (TOML or preset) or ``--klipper-config``,
    default the ``klipper`` preset; ``--flavor`` overrides the machine's flavor."""
    machine_spec = getattr(args, "machine", None)
    klipper_cfg = getattr(args, "klipper_config", None)
    linuxcnc_ini = getattr(args, "linuxcnc_ini", None)
    if sum(bool(x) for x in (machine_spec, klipper_cfg, linuxcnc_ini)) > 1:
        raise ConfigError("give one of --machine, --klipper-config, --linuxcnc-ini, not both")
    if linuxcnc_ini:
        from .linuxcnc_ini import load_linuxcnc_ini

        machine = load_linuxcnc_ini(linuxcnc_ini)
    elif klipper_cfg:
        machine = load_klipper_config(klipper_cfg)
    else:
        machine = load_machine(machine_spec or "klipper")
    flavor = getattr(args, "flavor", None)
    if flavor:
        problem = _rule_choice(FLAVORS)(flavor)
        if problem is not None:
            raise ConfigError(f"--flavor: {problem}")
        machine = replace(machine, flavor=flavor)
    if getattr(args, "no_bounds", False):
        machine = without_bounds(machine)
    return machine


def without_bounds(machine: Machine) -> Machine:
    """A copy of ``machine`` with no travel limits (position_min/max ∓inf) on any axis: ``--no-bounds``."""
    axes = {a: replace(ax, position_min=-math.inf, position_max=math.inf) for a, ax in machine.axes.items()}
    return replace(machine, axes=axes)
