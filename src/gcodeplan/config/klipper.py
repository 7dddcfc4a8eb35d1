"""Klipper's printer.cfg read as Klipper reads it (configparser rules, includes, SAVE_CONFIG), into a Machine."""
from __future__ import annotations

import glob as _glob
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError
from .fields import UNSUPPORTED_KINEMATICS, klipper_extrude_ratio, parse_gear_ratio, steps_per_mm_from_rotation, validate
from .toml import read_text
from ..machine import KINEMATICS, SHAPER_TYPES, Axis, Machine


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


class KlipperCfg:
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
    def read(self) -> "KlipperCfg":
        text = read_text(self.main).replace("\r\n", "\n")
        regular, autosave = self._split_autosave(text)
        visiting = (os.path.abspath(self.main),)
        self._parse(list(enumerate(_cfg_lines(regular), start=1)), self.main, visiting)
        saved = KlipperCfg(self.main)
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
            # an included file may be anything ([include /etc/shadow]): its lines are never quoted, only
            # its path and the line number (the user's own file is quoted, to show what is wrong)
            included = len(visiting) > 1
            if section is None:
                if included:
                    raise ConfigError("not a Klipper config line (a line outside any [section])", file, n)
                raise ConfigError(f"'{content}' is outside any [section]", file, n)
            sep = _OPTION_SEP.search(content)
            if sep is None or not content[:sep.start()].strip():
                if included:
                    raise ConfigError("not a Klipper config line (expected 'key: value')", file, n)
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
            text = read_text(path)
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


def _klipper_travel_limits(cfg: KlipperCfg, section: str, axis: Axis) -> None:
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


def _steps_per_rotation(cfg: KlipperCfg, section: str) -> tuple[int, int, float]:
    """(microsteps, full_steps_per_rotation, gear_ratio) of a stepper section, checked as Klipper's stepper.py
    ``parse_step_distance`` checks them (full steps a multiple of 4)."""
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
    return microsteps, full_steps, ratio


def _klipper_steps_per_mm(cfg: KlipperCfg, section: str) -> float:
    """Klipper stepper.py: step_distance = rotation_distance / (full_steps · microsteps · gear_ratio)."""
    rotation_distance = cfg.get_float(section, "rotation_distance", required=True, above=0.0)
    microsteps, full_steps, ratio = _steps_per_rotation(cfg, section)
    return steps_per_mm_from_rotation(rotation_distance, microsteps, full_steps, ratio)


def load_klipper_config(path: str) -> Machine:
    """A machine from a Klipper printer.cfg: flavor, firmware model and junction policy "klipper".

    Reads [printer], [stepper_x|y|z], [extruder], [gcode_arcs], [firmware_retraction] with Klipper's
    defaults and range checks; other sections and keys are ignored (they do not change planned times).
    """
    cfg = KlipperCfg(str(path)).read()
    if not cfg.has("printer"):
        raise ConfigError("[printer] section is required", cfg.main)

    kin_value = cfg.raw("printer", "kinematics")
    if kin_value is None:
        raise ConfigError("[printer] kinematics is required", cfg.main)
    kinematics = kin_value.text.strip().lower()
    plugin = _plugin(kinematics)
    if kinematics not in KINEMATICS and plugin is None:
        reason = UNSUPPORTED_KINEMATICS.get(kinematics, f"kinematics {kinematics!r} is not supported")
        raise ConfigError(f"[printer] kinematics: {reason} (supported: {', '.join(KINEMATICS)})",
                          kin_value.file, kin_value.line)

    m = Machine(name=Path(path).stem, kinematics=kinematics, flavor="klipper", firmware="klipper",
                junction_policy="klipper")
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
    own_sections = kinematics == "delta" or getattr(plugin, "from_klipper", None) is not None
    for a in ("x", "y", "z") if not own_sections else ():
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
    if getattr(plugin, "from_klipper", None) is not None:
        # a plug-in kinematics reads its own sections (and may take the Z limits back: rotary_delta, winch)
        plugin.from_klipper(cfg, m)

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


def _plugin(kinematics: str):
    """The registered plug-in of ``kinematics`` (built-ins included), None for the legacy four and unknown names."""
    from ..kinematics import plugin as kin_plugin

    if kinematics in ("cartesian", "corexy", "corexz", "delta"):
        return None
    try:
        return kin_plugin.registered(kinematics)
    except ConfigError:
        return None


def klipper_rail(cfg: KlipperCfg, section: str, axis: Axis) -> float:
    """stepper.py PrinterRail for a plug-in's linear rail: steps/mm (returned), position_endstop into
    ``axis.home`` and position_min/max into ``axis`` (ConfigError when the section is missing)."""
    if not cfg.has(section):
        raise ConfigError(f"[{section}] section is required", cfg.main)
    spm = _klipper_steps_per_mm(cfg, section)
    axis.home = cfg.get_float(section, "position_endstop", 0.0)
    _klipper_travel_limits(cfg, section, axis)
    return spm


def klipper_steps_per_rad(cfg: KlipperCfg, section: str) -> float:
    """stepper.py parse_step_distance with units_in_radians: one turn (2π rad) is
    full_steps · microsteps · gear_ratio steps (rotation_distance is not read)."""
    if not cfg.has(section):
        raise ConfigError(f"[{section}] section is required", cfg.main)
    microsteps, full_steps, ratio = _steps_per_rotation(cfg, section)
    return full_steps * microsteps * ratio / (2.0 * math.pi)


def _klipper_delta(cfg: KlipperCfg, m: Machine) -> None:
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
    from ..kinematics.delta import DeltaGeometry

    home = DeltaGeometry.from_machine(m).home_position
    for a, h in zip("xyz", home):
        m.axes[a].home = h


def _klipper_extruder(cfg: KlipperCfg, m: Machine) -> None:
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


def _klipper_input_shaper(cfg: KlipperCfg, m: Machine) -> None:
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


