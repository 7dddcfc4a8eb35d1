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
from .machine import AXES, FLAVORS, KINEMATICS, POLICIES, Axis, Machine

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
]

# Kinematics Klipper and others offer that we know about but cannot plan yet.
_UNSUPPORTED_KINEMATICS = {
    "delta": "delta is not supported yet",
    "deltesian": "deltesian is not supported yet",
    "rotary_delta": "rotary_delta is not supported yet",
    "polar": "polar is not supported yet",
    "corexz": "corexz is not supported yet",
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
        close = difflib.get_close_matches(v, allowed, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return f"unknown value {v!r}: must be one of {', '.join(allowed)}{hint}"
    return rule


def _rule_string(v: Any) -> str | None:
    return None if isinstance(v, str) else "must be a string"


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
    _Field("stepper", "max_step_rate", "max_step_rate", _rule_positive_or_inf, "number", "steps/s"),
)

# Keys that are read but are not Machine fields: they are turned into one.
_AXIS_STEP_KEYS = ("rotation_distance", "microsteps", "full_steps_per_rotation", "gear_ratio")
_EXTRUDER_EXTRA_KEYS = ("max_extrude_cross_section",)
_TOP_EXTRA_KEYS = ("base",)

_SECTIONS = ("toolhead", "junction", "axis", "extruder", "arcs", "firmware_retraction", "time", "stepper")


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
    # Klipper's corner rule takes δ = scv²·(√2−1)/max_accel and multiplies it back by the accel:
    # with an infinite max_accel that is inf·0, no answer at all.
    if machine.junction_policy == "klipper" and not math.isfinite(machine.max_accel):
        raise ConfigError("toolhead.max_accel: must be finite with junction.policy 'klipper', got inf", source)


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

def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(float(v))


def machine_to_toml(machine: Machine) -> str:
    """The machine in gcodeplan's TOML format; ``load_machine`` of the text gives an equal Machine."""
    validate(machine)
    out: list[str] = []
    current = ""
    for f in _FIELDS:
        if f.section == "axis":
            continue
        value = getattr(machine, f.attr)
        if value is None:
            continue     # None = "use max_accel / max_velocity": omitting the key keeps it
        if f.section != current:
            current = f.section
            out.append(f"\n[{f.section}]")
        out.append(f"{f.key} = {_toml_value(value)}")
    for a in AXES:
        out.append(f"\n[axis.{a}]")
        for f in _FIELDS:
            if f.section == "axis":
                out.append(f"{f.key} = {_toml_value(getattr(machine.axes[a], f.attr))}")
    return "\n".join(out).lstrip("\n") + "\n"


# ============================================================================ Klipper printer.cfg

_AUTOSAVE_MARK = re.compile(r"^#\*#\s*<-+\s*SAVE_CONFIG\s*-+>\s*$")
_SECTION_RE = re.compile(r"^\[(?P<name>[^\]]+)\]$")
_INLINE_COMMENT = re.compile(r"\s[#;]")


@dataclass
class _CfgValue:
    text: str
    file: str
    line: int


class _KlipperCfg:
    """The sections of a printer.cfg after includes and the SAVE_CONFIG block, with each value's origin."""

    def __init__(self, main: str):
        self.main = main
        self.sections: dict[str, dict[str, _CfgValue]] = {}

    # -- reading
    def read(self) -> "_KlipperCfg":
        text = _read_text(self.main)
        lines = text.splitlines()
        numbered = list(enumerate(lines, start=1))
        autosave: list[tuple[int, str]] = []
        for i, (_, raw) in enumerate(numbered):
            if _AUTOSAVE_MARK.match(raw.strip()):
                autosave = numbered[i + 1:]
                numbered = numbered[:i]
                break
        self._parse(numbered, self.main, visiting=(os.path.abspath(self.main),))
        # Klipper reads the auto-saved block after everything else, so its values win.
        self._parse(self._unwrap_autosave(autosave), self.main, visiting=(os.path.abspath(self.main),))
        return self

    def _unwrap_autosave(self, lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
        out = []
        for n, raw in lines:
            if not raw.strip():
                continue
            if not raw.startswith("#*#"):
                raise ConfigError("a line after the SAVE_CONFIG marker must start with '#*#'", self.main, n)
            body = raw[3:]
            body = body[1:] if body.startswith(" ") else body
            if body.strip().upper().startswith("DO NOT EDIT"):
                continue
            out.append((n, body))
        return out

    def _parse(self, lines: list[tuple[int, str]], file: str, visiting: tuple[str, ...]) -> None:
        section: str | None = None
        key: str | None = None
        key_indent = 0
        for n, raw in lines:
            stripped = raw.strip()
            if not stripped or stripped[0] in "#;":
                continue
            m = _INLINE_COMMENT.search(raw)
            content = raw[:m.start()] if m else raw
            indent = len(content) - len(content.lstrip())
            content = content.strip()
            if not content:
                continue
            if indent > key_indent and key is not None and section is not None:
                prev = self.sections[section][key]
                prev.text = (prev.text + "\n" + content) if prev.text else content
                continue
            ms = _SECTION_RE.match(content)
            if ms:
                name = ms.group("name").strip()
                key = None
                if name.startswith("include "):
                    self._include(name[len("include "):].strip(), file, n, visiting)
                    section = None       # keys after an include need their own [section]
                    continue
                section = name
                self.sections.setdefault(section, {})
                continue
            if section is None:
                raise ConfigError(f"'{content}' is outside any [section]", file, n)
            seps = [i for i in (content.find(":"), content.find("=")) if i > 0]
            if not seps:
                raise ConfigError(f"[{section}]: expected 'key: value', got {content!r}", file, n)
            i = min(seps)
            key = content[:i].strip().lower()
            key_indent = indent
            self.sections[section][key] = _CfgValue(content[i + 1:].strip(), file, n)

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
            self._parse(list(enumerate(text.splitlines(), start=1)), path, visiting + (absolute,))

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

    for a in ("x", "y", "z"):
        section = f"stepper_{a}"
        if not cfg.has(section):
            raise ConfigError(f"[{section}] section is required", cfg.main)
        m.axes[a].steps_per_mm = _klipper_steps_per_mm(cfg, section)
        m.axes[a].home = cfg.get_float(section, "position_endstop", 0.0)
    # cartesian.py / corexy.py: only Z has limits of its own; X/Y stay unlimited (inf).
    m.axes["z"].max_velocity = cfg.get_float("printer", "max_z_velocity", m.max_velocity,
                                             above=0.0, maxval=m.max_velocity)
    m.axes["z"].max_accel = cfg.get_float("printer", "max_z_accel", m.max_accel, above=0.0, maxval=m.max_accel)

    if cfg.has("extruder"):
        _klipper_extruder(cfg, m)
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


# ============================================================================ CLI

def machine_from_args(args: Any) -> Machine:
    """The machine a command runs with: ``--machine`` (TOML or preset) or ``--klipper-config``,
    default the ``klipper`` preset; ``--flavor`` overrides the machine's flavor."""
    machine_spec = getattr(args, "machine", None)
    klipper_cfg = getattr(args, "klipper_config", None)
    if machine_spec and klipper_cfg:
        raise ConfigError("give --machine or --klipper-config, not both")
    if klipper_cfg:
        machine = load_klipper_config(klipper_cfg)
    else:
        machine = load_machine(machine_spec or "klipper")
    flavor = getattr(args, "flavor", None)
    if flavor:
        problem = _rule_choice(FLAVORS)(flavor)
        if problem is not None:
            raise ConfigError(f"--flavor: {problem}")
        machine = replace(machine, flavor=flavor)
    return machine
