"""gcodeplan's machine TOML format: presets, loading (with ``base =`` inheritance) and writing."""
from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from importlib import resources
from typing import Any

from ..errors import ConfigError
from .fields import AXIS_STEP_KEYS, EXTRUDER_EXTRA_KEYS, FIELDS, Field, SECTIONS, is_number, klipper_extrude_ratio, parse_gear_ratio, rule_positive_or_inf, section_keys, show_value, steps_per_mm_from_rotation, toml_path, validate
from ..machine import AXES, Machine, firmware_policy_conflict, policy_of_firmware


# ============================================================================ TOML

def preset_names() -> list[str]:
    """Names of the machines shipped in gcodeplan/presets (``load_preset(name)`` reads them)."""
    folder = resources.files("gcodeplan").joinpath("presets")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def preset_path(name: str) -> str:
    """Display name of a preset's file, used in messages (``presets/klipper.toml``)."""
    return f"presets/{name}.toml"


def _preset_text(name: str) -> str:
    return resources.files("gcodeplan").joinpath("presets", f"{name}.toml").read_text(encoding="utf-8")


def load_preset(name: str) -> Machine:
    """The machine of a preset shipped in gcodeplan/presets (``klipper``, ``marlin``, ``grbl``, …)."""
    return _load_toml_text(_preset_text(name), preset_path(name), base_dir=None, seen=(name,))


def load_machine_toml(path: str, _seen: tuple[str, ...] = ()) -> Machine:
    """A machine from a gcodeplan TOML file (format: docs/machine.md)."""
    text = read_text(path)
    return _load_toml_text(text, str(path), base_dir=os.path.dirname(os.path.abspath(path)),
                           seen=_seen + (os.path.abspath(path),))


def read_text(path: str) -> str:
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
    except RecursionError:
        # tomllib parses nested arrays/tables recursively: thousands of '[' exhaust Python's stack
        raise ConfigError("TOML nested too deeply (arrays or inline tables inside each other by the "
                          "thousand): not a machine description", source) from None

    machine = _base_machine(doc.get("base"), source, base_dir, seen)
    _apply_toml(doc, machine, source)
    junction = doc.get("junction")
    _settle_firmware_policy(machine, "firmware" in doc, isinstance(junction, dict) and "policy" in junction, source)
    validate(machine, source)
    return machine


def _settle_firmware_policy(machine: Machine, firmware_named: bool, policy_named: bool, source: str) -> None:
    """Klipper and LinuxCNC plan with their own policy (machine.firmware_policy_conflict): a file naming both
    the firmware and another policy is an error; a file naming one of them over its ``base`` takes the other
    along (``firmware = "linuxcnc"`` over the klipper preset plans with the linuxcnc policy; ``policy = "blend"``
    over it makes the firmware generic, since Klipper has no blend)."""
    problem = firmware_policy_conflict(machine.firmware, machine.junction_policy)
    if problem is None:
        return
    if firmware_named == policy_named:      # both in this file (or neither: a base cannot conflict)
        raise ConfigError(problem, source)
    if firmware_named:
        machine.junction_policy = policy_of_firmware(machine.firmware)
    else:
        machine.firmware = "generic"


def _base_machine(base: Any, source: str, base_dir: str | None, seen: tuple[str, ...]) -> Machine:
    """``base = "marlin"`` (a preset) or ``base = "other.toml"`` (relative to this file): start from it."""
    if base is None:
        return Machine()
    if not isinstance(base, str):
        raise ConfigError(f"base: must be a string (a preset name or a TOML file), got {show_value(base)}", source)
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
    top_keys = section_keys("")
    for key, value in doc.items():
        if key == "kinematics_params":
            # a plug-in kinematics' own settings (gcodeplan.kinematics.plugin): its names, numbers / arrays
            if not isinstance(value, dict):
                raise ConfigError(f"kinematics_params: must be a table, got {show_value(value)}", source)
            machine.kinematics_params = dict(value)
            continue
        if isinstance(value, dict):
            if key not in SECTIONS:
                raise ConfigError(_unknown(key, "section", list(SECTIONS)), source)
            if key == "axis":
                _apply_axes(value, machine, source)
            else:
                _apply_section(key, value, machine, source)
        elif key in top_keys:
            if key != "base":
                _set(machine, _field("", key), value, source)
        elif key in SECTIONS:
            raise ConfigError(f"{key}: must be a table [{key}], got {show_value(value)}", source)
        else:
            owners = [s for s in SECTIONS if key in section_keys(s)]
            if owners:
                where = "axis.<x|y|z|e>" if owners[0] == "axis" else owners[0]
                raise ConfigError(f"{key}: unknown top-level key (it belongs in [{where}])", source)
            raise ConfigError(_unknown(key, "key", top_keys + list(SECTIONS)), source)


def _field(section: str, key: str) -> Field:
    for f in FIELDS:
        if f.section == section and f.key == key:
            return f
    raise KeyError((section, key))


def _coerce(f: Field, value: Any, path: str, source: str) -> Any:
    """TOML value → Python value of the field's kind; only type errors here, ranges in the rule."""
    if f.kind == "string":
        if not isinstance(value, str):
            raise ConfigError(f"{path}: must be a string, got {show_value(value)}", source)
        return value
    if f.kind == "table":
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: must be a table, got {show_value(value)}", source)
        return {str(k): (float(t) if is_number(t) else t) for k, t in value.items()}
    if f.kind == "triple":
        # one number for the three towers, or [a, b, c]
        vals = value if isinstance(value, list) else [value] * 3
        if len(vals) != 3 or not all(is_number(x) for x in vals):
            raise ConfigError(f"{path}: must be a number or an array of three numbers (towers a, b, c), "
                              f"got {show_value(value)}", source)
        return tuple(float(x) for x in vals)
    if isinstance(value, str) and value.strip().lower() in ("inf", "+inf", "infinity"):
        return math.inf
    if not is_number(value):
        raise ConfigError(f"{path}: must be a number, got {show_value(value)}", source)
    return float(value)


def _set(target: Any, f: Field, value: Any, source: str, axis: str | None = None) -> None:
    path = toml_path(f, axis)
    v = _coerce(f, value, path, source)
    problem = f.rule(v)
    if problem is not None:
        raise ConfigError(f"{path}: {problem}, got {show_value(value)}", source)
    setattr(target, f.attr, v)


def _apply_section(section: str, table: dict[str, Any], machine: Machine, source: str) -> None:
    known = section_keys(section)
    for key, value in table.items():
        if key not in known:
            raise ConfigError(_unknown(f"{section}.{key}", "key", known), source)
        if key in EXTRUDER_EXTRA_KEYS:
            continue
        _set(machine, _field(section, key), value, source)
    if section == "extruder" and "max_extrude_cross_section" in table:
        if "max_extrude_ratio" in table:
            raise ConfigError("extruder.max_extrude_cross_section: give it or max_extrude_ratio, not both",
                              source)
        path = "extruder.max_extrude_cross_section"
        raw = table["max_extrude_cross_section"]
        cross = _coerce(_field("extruder", "max_extrude_ratio"), raw, path, source)
        problem = rule_positive_or_inf(cross)
        if problem is not None:
            raise ConfigError(f"{path}: {problem}, got {show_value(raw)}", source)
        machine.max_extrude_ratio = klipper_extrude_ratio(cross, machine.filament_diameter)


def _apply_axes(table: dict[str, Any], machine: Machine, source: str) -> None:
    known = section_keys("axis")
    for a, sub in table.items():
        if a not in AXES:
            raise ConfigError(f"axis.{a}: unknown axis (axes are {', '.join(AXES)})", source)
        if not isinstance(sub, dict):
            raise ConfigError(f"axis.{a}: must be a table [axis.{a}], got {show_value(sub)}", source)
        ax = machine.axes[a]
        for key, value in sub.items():
            if key not in known:
                raise ConfigError(_unknown(f"axis.{a}.{key}", "key", known), source)
            if key not in AXIS_STEP_KEYS:
                _set(ax, _field("axis", key), value, source, axis=a)
        if any(k in sub for k in AXIS_STEP_KEYS):
            ax.steps_per_mm = _steps_from_toml(a, sub, source)


def _steps_from_toml(a: str, sub: dict[str, Any], source: str) -> float:
    p = f"axis.{a}"
    if "steps_per_mm" in sub:
        raise ConfigError(f"{p}.steps_per_mm: give steps_per_mm or rotation_distance (+ microsteps), not both",
                          source)
    if "rotation_distance" not in sub:
        extra = next(k for k in AXIS_STEP_KEYS if k in sub)
        raise ConfigError(f"{p}.{extra}: needs {p}.rotation_distance", source)
    if "microsteps" not in sub:
        raise ConfigError(f"{p}.microsteps: required with rotation_distance", source)
    rd = sub["rotation_distance"]
    if not is_number(rd) or not (rd > 0 and math.isfinite(rd)):
        raise ConfigError(f"{p}.rotation_distance: must be a positive finite number, got {show_value(rd)}", source)

    def integer(key: str, default: int) -> int:
        v = sub.get(key, default)
        if not is_number(v) or not math.isfinite(v) or v != int(v) or v < 1:
            raise ConfigError(f"{p}.{key}: must be a positive integer, got {show_value(v)}", source)
        return int(v)

    microsteps = integer("microsteps", 16)
    full_steps = integer("full_steps_per_rotation", 200)
    ratio = sub.get("gear_ratio", 1.0)
    if isinstance(ratio, str):
        try:
            ratio = parse_gear_ratio(ratio)
        except ValueError as err:
            raise ConfigError(f"{p}.gear_ratio: {err}", source) from None
    elif not is_number(ratio) or not (ratio > 0 and math.isfinite(ratio)):
        raise ConfigError(f"{p}.gear_ratio: must be a positive number or 'a:b, c:d', got {show_value(ratio)}", source)
    steps = steps_per_mm_from_rotation(float(rd), microsteps, full_steps, float(ratio))
    problem = _field("axis", "steps_per_mm").rule(steps)
    if problem is not None:
        raise ConfigError(f"{p}.rotation_distance: full_steps_per_rotation·microsteps·gear_ratio / rotation_distance "
                          f"= {steps:g} steps/mm; steps_per_mm {problem}", source)
    return steps


# ---------------------------------------------------------------------------- writer

def machine_to_toml(machine: Machine) -> str:
    """The machine in gcodeplan's TOML format; ``load_machine`` of the text gives an equal Machine.

    Written with tomli-w, which escapes every string TOML can hold (tabs, newlines, control
    characters, quotes) and spells ±inf the TOML way."""
    import tomli_w

    validate(machine)
    doc: dict[str, Any] = {}
    for f in FIELDS:
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
    doc["axis"] = {a: {f.key: float(getattr(machine.axes[a], f.attr)) for f in FIELDS if f.section == "axis"}
                   for a in AXES}
    if machine.kinematics_params:
        doc["kinematics_params"] = dict(machine.kinematics_params)
    return tomli_w.dumps(doc)


