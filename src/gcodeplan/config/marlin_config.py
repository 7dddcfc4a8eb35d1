"""A machine from a Marlin build's ``Configuration.h`` (with its ``Configuration_adv.h``), run on the
``marlin-2.1.2`` firmware model (planner/marlin.py).

Recognised by content (:func:`is_marlin_config`): C preprocessor text that defines ``CONFIGURATION_H_VERSION``
or ``DEFAULT_AXIS_STEPS_PER_UNIT`` (``CONFIGURATION_ADV_H_VERSION`` for the advanced file).
``--machine Configuration.h`` also reads the ``Configuration_adv.h`` beside it (same folder; a file named
``X_Configuration.h`` looks for ``X_Configuration_adv.h`` first); ``--machine Configuration_adv.h`` reads the
``Configuration.h`` beside it, which must exist. Without an advanced file Marlin 2.1.2's shipped defaults for
its settings are taken, and a warning says so.

How the text is read (the preprocessor as far as configuration files use it):

* ``#define NAME value`` sets NAME (an empty value = the option is on); ``//#define NAME …`` (commented out) is
  off; ``#undef NAME`` removes it; comments (``//``, ``/* */``) and ``\\`` line continuations are honoured;
* values are numbers, brace arrays ``{ 80, 80, 400, 500 }`` (X, Y, Z, E0 [, E1 …] with DISTINCT_E_FACTORS:
  the first extruder is taken, the others named in a warning) and arithmetic on numbers and earlier names
  (``X_BED_SIZE + 10``, ``(200*16)/(2*20)``);
* ``#if ENABLED(A)``/``DISABLED``/``ANY``/``ALL``/``BOTH``/``NONE``, ``#ifdef``/``#ifndef``, ``defined(A)``,
  ``!``, ``&&``, ``||``, ``#elif``, ``#else`` and ``#endif`` are evaluated on what has been defined so far
  (the two files in order: Configuration.h, then Configuration_adv.h). Any other condition (``#if HAS_MEDIA``,
  ``#if AXIS_IS_TMC(X)``, comparisons) is taken as true, and a setting gcodeplan reads that is defined inside
  such a block is named in a warning.

What is read: DEFAULT_AXIS_STEPS_PER_UNIT, DEFAULT_MAX_FEEDRATE, DEFAULT_MAX_ACCELERATION,
DEFAULT_ACCELERATION / _RETRACT_ / _TRAVEL_ACCELERATION, CLASSIC_JERK with DEFAULT_X/Y/Z/EJERK or
JUNCTION_DEVIATION_MM, S_CURVE_ACCELERATION, LIN_ADVANCE with ADVANCE_K (LIN_ADVANCE_K), ARC_SUPPORT with
MIN/MAX_ARC_SEGMENT_MM (MM_PER_ARC_SEGMENT), MIN_CIRCLE_SEGMENTS, ARC_SEGMENTS_PER_SEC, N_ARC_CORRECTION,
ARC_P_CIRCLES, and the travel (X/Y/Z_MIN_POS, _MAX_POS with MIN/MAX_SOFTWARE_ENDSTOPS). Settings the model
runs at fixed values (MINIMUM_PLANNER_SPEED 0.05, DEFAULT_MINSEGMENTTIME 20000, MIN_STEPS_PER_SEGMENT 6,
SLOWDOWN with divisor 2, JD_HANDLE_SMALL_SEGMENTS) are checked: another value is a named warning. BLOCK_BUFFER_SIZE
is the machine's ``marlin_block_buffer`` (the model's planner ring). Features that change the time and that the model does not run (INPUT_SHAPING_X/Y, FT_MOTION,
ADAPTIVE_STEP_SMOOTHING, XY_FREQUENCY_LIMIT, BACKLASH_COMPENSATION, bed levelling, …) are named warnings;
COREXY and COREXZ give the corexy and corexz kinematics (Marlin's Core builds); another kinematics is an error.
The switches that add G codes (INCH_MODE_SUPPORT, CNC_WORKSPACE_PLANES, GCODE_MOTION_MODES, and the refused
CNC_COORDINATE_SYSTEMS, SAVED_POSITIONS, BEZIER_CURVE_SUPPORT, G38_PROBE_TARGET: gcodeplan/marlin_build.py) become
the machine's ``marlin_build``; FWRETRACT's RETRACT_LENGTH, RETRACT_FEEDRATE, RETRACT_RECOVER_LENGTH and
RETRACT_RECOVER_FEEDRATE its ``[firmware_retraction]`` (off: G10/G11 move nothing).
"""
from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import replace

from ..errors import ConfigError

_DEFINE = re.compile(r"^\s*#\s*define\s+([A-Za-z_]\w*)(\([^)]*\))?\s*(.*)$")
_COMMENTED_DEFINE = re.compile(r"^\s*//\s*#\s*define\s+([A-Za-z_]\w*)")
_DIRECTIVE = re.compile(r"^\s*#\s*(\w+)\s*(.*)$")
_MAIN_KEYS = ("CONFIGURATION_H_VERSION", "DEFAULT_AXIS_STEPS_PER_UNIT")
_ADV_KEY = "CONFIGURATION_ADV_H_VERSION"

#: Marlin 2.1.2's shipped Configuration_adv.h values of the settings read from it (used without the file)
ADV_DEFAULTS = {"ARC_SUPPORT": "", "MIN_ARC_SEGMENT_MM": "0.1", "MAX_ARC_SEGMENT_MM": "1.0",
                "MIN_CIRCLE_SEGMENTS": "72", "N_ARC_CORRECTION": "25", "DEFAULT_MINSEGMENTTIME": "20000",
                "SLOWDOWN": "", "SLOWDOWN_DIVISOR": "2", "MINIMUM_PLANNER_SPEED": "0.05",
                "MIN_STEPS_PER_SEGMENT": "6", "BLOCK_BUFFER_SIZE": "16", "DEFAULT_MINIMUMFEEDRATE": "0.0",
                "DEFAULT_MINTRAVELFEEDRATE": "0.0"}

#: settings the model runs at one value: (value, what)
FIXED = {"MINIMUM_PLANNER_SPEED": (0.05, "mm/s, the slowest junction/stop speed"),
         "DEFAULT_MINSEGMENTTIME": (20000, "µs, SLOWDOWN's minimum segment time (M205 B)"),
         "MIN_STEPS_PER_SEGMENT": (6, "steps, shorter moves merge into the next"),
         "SLOWDOWN_DIVISOR": (2, "SLOWDOWN's buffer fraction")}

#: options on that change the time of a program and that the model does not run
UNMODELLED = {
    "INPUT_SHAPING_X": "input shaping on X (M593)", "INPUT_SHAPING_Y": "input shaping on Y (M593)",
    "INPUT_SHAPING_Z": "input shaping on Z (M593)",
    "FT_MOTION": "fixed-time motion (a different planner and stepper)",
    "ADAPTIVE_STEP_SMOOTHING": "adaptive step smoothing (changes the step timing)",
    "XY_FREQUENCY_LIMIT": "XY frequency limit (slows short zig-zags)",
    "BACKLASH_COMPENSATION": "backlash compensation (extra correction steps)",
    "DIRECT_STEPPING": "direct stepping (page moves)",
    "NONLINEAR_EXTRUSION": "non-linear extrusion",
    "SHAPING_MENU": None,
    "MESH_BED_LEVELING": "mesh bed levelling (Z corrections; moves split at the mesh lines when on)",
    "AUTO_BED_LEVELING_BILINEAR": "bilinear bed levelling (Z corrections; moves split at the grid when on)",
    "AUTO_BED_LEVELING_UBL": "unified bed levelling (Z corrections; segmented moves when on)",
    "AUTO_BED_LEVELING_LINEAR": "linear bed levelling (Z corrections)",
    "AUTO_BED_LEVELING_3POINT": "3-point bed levelling (Z corrections)",
    "SKEW_CORRECTION": "skew correction (changes every move's XY)",
    "LASER_POWER_TRAPEZOID": "laser power trapezoid",
    "SCARA_FEEDRATE_SCALING": "SCARA feed rate scaling",
    "EXTRA_LIN_ADVANCE_K": "a second linear advance factor (M900 L/S)",
    "DISTINCT_E_FACTORS": None,
}
#: the Core builds the model runs (planner/marlin.py: blocks, limits and pulses per motor), as gcodeplan's kinematics
CORE_KINEMATICS = {"COREXY": "corexy", "COREXZ": "corexz"}
#: kinematics the model cannot run
KINEMATICS = ("DELTA", "COREYZ", "COREYX", "COREZX", "COREZY", "MARKFORGED_XY",
              "MARKFORGED_YX", "MORGAN_SCARA", "MP_SCARA", "AXEL_TPARA", "POLARGRAPH", "POLAR", "ARTICULATED_ROBOT_ARM",
              "FOAMCUTTER_XYUV")
#: settings this module reads (a warning names them when defined under a condition it could not evaluate)
READ = {"DEFAULT_AXIS_STEPS_PER_UNIT", "DEFAULT_MAX_FEEDRATE", "DEFAULT_MAX_ACCELERATION", "DEFAULT_ACCELERATION",
        "DEFAULT_RETRACT_ACCELERATION", "DEFAULT_TRAVEL_ACCELERATION", "CLASSIC_JERK", "DEFAULT_XJERK",
        "DEFAULT_YJERK", "DEFAULT_ZJERK", "DEFAULT_EJERK", "JUNCTION_DEVIATION_MM", "S_CURVE_ACCELERATION",
        "LIN_ADVANCE", "ADVANCE_K", "LIN_ADVANCE_K", "ARC_SUPPORT", "MIN_ARC_SEGMENT_MM", "MAX_ARC_SEGMENT_MM",
        "MM_PER_ARC_SEGMENT", "MIN_CIRCLE_SEGMENTS", "ARC_SEGMENTS_PER_SEC", "N_ARC_CORRECTION",
        "ARC_P_CIRCLES", "JD_HANDLE_SMALL_SEGMENTS", "SLOWDOWN", "DEFAULT_MINIMUMFEEDRATE",
        "DEFAULT_MINTRAVELFEEDRATE", "INCH_MODE_SUPPORT", "CNC_WORKSPACE_PLANES", "GCODE_MOTION_MODES",
        "CNC_COORDINATE_SYSTEMS", "SAVED_POSITIONS", "BEZIER_CURVE_SUPPORT", "G38_PROBE_TARGET", "FWRETRACT",
        "RETRACT_LENGTH", "RETRACT_FEEDRATE", "RETRACT_RECOVER_LENGTH", "RETRACT_RECOVER_FEEDRATE", "RETRACT_ZRAISE",
        "BLOCK_BUFFER_SIZE", *FIXED, *UNMODELLED,
        *KINEMATICS, *CORE_KINEMATICS}


# ============================================================================ recognising

def _head(path: str) -> str | None:
    try:
        with open(path, "rb") as fh:
            return fh.read(1 << 20).decode("utf-8-sig", errors="replace")
    except OSError:
        return None


def _defines_name(text: str, name: str) -> bool:
    return re.search(r"^\s*#\s*define\s+" + name + r"\b", text, re.MULTILINE) is not None


def is_marlin_config(path: str) -> bool:
    """True when the file is a Marlin ``Configuration.h`` or ``Configuration_adv.h`` (see the module docstring)."""
    text = _head(path)
    if text is None:
        return False
    return any(_defines_name(text, k) for k in _MAIN_KEYS + (_ADV_KEY,))


def _sibling(path: str, adv: bool) -> str:
    """The other file of the pair in the same folder (see the module docstring)."""
    folder, name = os.path.split(path)
    a, b = ("Configuration.h", "Configuration_adv.h") if not adv else ("Configuration_adv.h", "Configuration.h")
    if a in name:
        cand = os.path.join(folder, name.replace(a, b))
        if os.path.isfile(cand):
            return cand
    return os.path.join(folder, b)


# ============================================================================ the preprocessor, as configs use it

def _logical_lines(text: str):
    """(line number, text) with block comments blanked and ``\\`` continuations joined (numbered by their first line)."""
    text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.DOTALL)
    buf, start = "", None
    for no, line in enumerate(text.splitlines(), 1):
        if start is None:
            start = no
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        yield start, buf + line
        buf, start = "", None
    if buf:
        yield start, buf


def _strip_comment(s: str) -> str:
    i = s.find("//")
    return s if i < 0 else s[:i]


class _Pre:
    """The defines of one or two files read in order, with their source (file, line) and whether each was set
    under a condition this reader could not evaluate."""

    def __init__(self):
        self.values: dict[str, str] = {}
        self.where: dict[str, tuple[str, int]] = {}
        self.off: dict[str, tuple[str, int]] = {}        # commented-out defines (for messages)
        self.unsure: dict[str, tuple[str, int, str]] = {}  # name → (file, line, condition)
        self.ignored_conditions: list[tuple[str, int, str]] = []

    def defined(self, name: str) -> bool:
        return name in self.values

    def enabled(self, name: str) -> bool:
        # Marlin's ENABLED(): defined, and not defined to 0/false
        return name in self.values and self.values[name].strip() not in ("0", "false")

    def _cond(self, expr: str) -> bool | None:
        """True/False, or None when the condition is not one this reader evaluates."""
        e = expr.strip()
        def call(m):
            fn, args = m.group(1), [a.strip() for a in m.group(2).split(",") if a.strip()]
            vals = [self.enabled(a) for a in args]
            if fn in ("ENABLED", "ANY", "EITHER"):
                return " 1 " if any(vals) else " 0 "
            if fn in ("ALL", "BOTH"):
                return " 1 " if all(vals) else " 0 "
            if fn in ("DISABLED", "NONE"):
                return " 1 " if not any(vals) else " 0 "
            return f" {m.group(0)} "
        e = re.sub(r"\b(ENABLED|DISABLED|ANY|ALL|BOTH|EITHER|NONE)\s*\(([^()]*)\)", call, e)
        e = re.sub(r"\bdefined\s*\(\s*(\w+)\s*\)", lambda m: " 1 " if self.defined(m.group(1)) else " 0 ", e)
        e = re.sub(r"\bdefined\s+(\w+)", lambda m: " 1 " if self.defined(m.group(1)) else " 0 ", e)
        py = e.replace("&&", " and ").replace("||", " or ")
        py = re.sub(r"!(?!=)", " not ", py)
        if not re.fullmatch(r"[\s01()]*(?:(?:and|or|not)[\s01()]*)*", py):
            return None
        try:
            return bool(eval(py, {"__builtins__": {}}, {}))     # only 0, 1, and, or, not, parentheses
        except Exception:
            return None

    def read(self, text: str, path: str) -> None:
        # stack of (taking this branch, a branch was taken, condition unknown)
        stack: list[list] = []
        for no, raw in _logical_lines(text):
            active = all(f[0] for f in stack)
            unsure = next((f[3] for f in stack if f[2]), None)
            m = _DIRECTIVE.match(raw)
            if not m:
                cm = _COMMENTED_DEFINE.match(raw)
                if cm and active:
                    self.off.setdefault(cm.group(1), (path, no))
                continue
            word, rest = m.group(1), _strip_comment(m.group(2)).strip()
            if word in ("if", "ifdef", "ifndef"):
                if word == "ifdef":
                    c = self.defined(rest.split()[0]) if rest else None
                elif word == "ifndef":
                    c = (not self.defined(rest.split()[0])) if rest else None
                else:
                    c = self._cond(rest)
                if c is None and active:
                    self.ignored_conditions.append((path, no, f"#{word} {rest}"))
                stack.append([True if c is None else c, c is None or c, c is None, f"#{word} {rest}"])
            elif word == "elif":
                if not stack:
                    raise ConfigError("#elif without #if", path, no)
                f = stack[-1]
                if f[1]:
                    f[0] = False
                else:
                    c = self._cond(rest)
                    f[0] = True if c is None else c
                    f[1] = f[0]
                    f[2] = f[2] or c is None
                    f[3] = f"#elif {rest}"
            elif word == "else":
                if not stack:
                    raise ConfigError("#else without #if", path, no)
                f = stack[-1]
                f[0] = not f[1]
                f[1] = True
            elif word == "endif":
                if not stack:
                    raise ConfigError("#endif without #if", path, no)
                stack.pop()
            elif not active:
                continue
            elif word == "define":
                d = _DEFINE.match(raw)
                if d and not d.group(2):          # function-like macros are not settings
                    name = d.group(1)
                    self.values[name] = _strip_comment(d.group(3)).strip()
                    self.where[name] = (path, no)
                    self.off.pop(name, None)
                    if unsure is not None:
                        self.unsure[name] = (path, no, unsure)
                    else:
                        self.unsure.pop(name, None)
            elif word == "undef":
                name = rest.split()[0] if rest else ""
                self.values.pop(name, None)
            elif word == "error":
                raise ConfigError(f"the configuration stops the build here: #error {rest}", path, no)
        if stack:
            raise ConfigError("#if without #endif at the end of the file", path)


# ============================================================================ values

_EXPR_OK = re.compile(r"[\d\s.+\-*/()eE]*")


def _number(pre: _Pre, name: str, text: str | None = None, depth: int = 0) -> float:
    """The value of a define (or of ``text``) as a number: numbers, earlier names and + − × ÷ ( )."""
    src = pre.values[name] if text is None else text
    path, no = pre.where.get(name, (None, None))
    s = re.sub(r"(\d)[fFlLuU]+\b", r"\1", src.strip())
    if depth < 8:
        s = re.sub(r"\b([A-Za-z_]\w*)\b",
                   lambda m: f"({_number(pre, m.group(1), depth=depth + 1)!r})" if m.group(1) in pre.values
                   and m.group(1) != name else m.group(0), s)
    if not s or not _EXPR_OK.fullmatch(s) or "**" in s or len(s) > 400:     # C has no power operator
        raise ConfigError(f"{name}: not a number gcodeplan can read: {src[:40]!r}", path, no)
    try:
        v = float(eval(s, {"__builtins__": {}}, {}))           # digits, operators and parentheses only
    except Exception:
        raise ConfigError(f"{name}: not a number gcodeplan can read: {src[:40]!r}", path, no) from None
    if not math.isfinite(v):
        raise ConfigError(f"{name} must be a finite number, got {src[:40]!r}", path, no)
    return v


def _array(pre: _Pre, name: str) -> list[float]:
    src = pre.values[name].strip()
    path, no = pre.where[name]
    if not (src.startswith("{") and src.endswith("}")):
        raise ConfigError(f"{name}: expected a brace list {{ X, Y, Z, E }}, got {src[:40]!r}", path, no)
    items = [x.strip() for x in src[1:-1].split(",") if x.strip()]
    if len(items) < 4:
        raise ConfigError(f"{name}: needs X, Y, Z and E values, got {len(items)}", path, no)
    return [_number(pre, name, t) for t in items]


# ============================================================================ the machine

def load_marlin_config(path: str, adv_path: str | None = None):
    """The :class:`~gcodeplan.machine.Machine` of a Marlin ``Configuration.h`` and ``Configuration_adv.h``
    (see the module docstring). ``path`` may be either file; the other is found beside it unless ``adv_path``
    names it."""
    from .fields import validate
    from .toml import load_preset

    notes: list[str] = []       # warnings, given (in order) when the reading ends, also on an error
    try:
        pre, main_path, adv, has_adv = _read_configs(path, adv_path, notes)
        machine = load_preset("marlin")
        axes = dict(machine.axes)
        top: dict = {"firmware": "marlin-2.1.2"}
        for define, kinematics in CORE_KINEMATICS.items():
            if pre.enabled(define):
                top["kinematics"] = kinematics
        _movement_settings(pre, axes, top, notes, main_path)
        _junction_settings(pre, axes, top, notes, main_path)
        _lin_advance_settings(pre, top, notes, main_path)
        top["marlin_arcs"] = _arc_settings(pre, top, notes, main_path)
        _fixed_and_unmodelled(pre, notes, main_path)
        _software_endstops(pre, axes)
        top["marlin_build"] = _build_switches(pre, notes, main_path)
        top["marlin_block_buffer"] = _block_buffer(pre, main_path)
        _fwretract_settings(pre, top, notes, main_path)
    finally:
        for msg in notes:
            warnings.warn(msg, stacklevel=2)
    name = os.path.basename(main_path) + (" + " + os.path.basename(adv) if has_adv else "")
    machine = replace(machine, axes=axes, name=f"marlin config ({name})", **top)
    validate(machine, main_path)
    return machine


def _note(pre: _Pre, notes: list[str], main_path: str, msg: str, name: str | None = None) -> None:
    """A warning about ``name``'s setting, located at its #define (or its disabled line), else the file."""
    where = pre.where.get(name) or pre.off.get(name) if name else None
    loc = f"{where[0]}:{where[1]}: " if where else f"{main_path}: "
    notes.append(loc + msg)


def _read_configs(path: str, adv_path: str | None, notes: list[str]):
    """Both files' #defines read (the main one first): (pre, main path, adv path, adv read). Without a
    Configuration_adv.h, Marlin 2.1.2's shipped values for the ones the model reads. Also the refusals and
    warnings of what cannot be read as written: settings under a condition not evaluated, kinematics other
    than cartesian and Core XY/XZ."""
    from .toml import read_text

    text = read_text(path)
    is_adv = _defines_name(text, _ADV_KEY) and not any(_defines_name(text, k) for k in _MAIN_KEYS)
    if is_adv:
        main = _sibling(path, adv=True)
        if not os.path.isfile(main):
            raise ConfigError("a Configuration_adv.h alone does not describe a machine: give the build's "
                              f"Configuration.h (no {os.path.basename(main)} beside this file)", path)
        adv, main_text, adv_text = path, read_text(main), text
        main_path = main
    else:
        main_path, main_text = path, text
        adv = adv_path or _sibling(path, adv=False)
        adv_text = read_text(adv) if os.path.isfile(adv) else None
        if adv_path and adv_text is None:
            raise ConfigError("no such file", adv_path)
    pre = _Pre()
    pre.read(main_text, main_path)
    if adv_text is not None:
        pre.read(adv_text, adv)
    else:
        for k, v in ADV_DEFAULTS.items():
            pre.values.setdefault(k, v)
        notes.append(f"{main_path}: no Configuration_adv.h beside it: Marlin 2.1.2's shipped values taken for "
                     "ARC_SUPPORT, MINIMUM_PLANNER_SPEED, DEFAULT_MINSEGMENTTIME, MIN_STEPS_PER_SEGMENT, "
                     "BLOCK_BUFFER_SIZE; LIN_ADVANCE off")

    for name, (f, no, cond) in sorted(pre.unsure.items()):
        if name in FIXED and _number(pre, name) == FIXED[name][0]:
            continue                    # the value the model runs anyway
        if name == "BLOCK_BUFFER_SIZE" and _number(pre, name) == 16:
            continue                    # Marlin's shipped file: 16 under #if HAS_MEDIA and in its #else
        if name in READ:
            notes.append(f"{f}:{no}: {name} is defined under '{cond}', a condition gcodeplan does not evaluate: "
                         "taken as if the condition held")

    for k in KINEMATICS:
        if pre.enabled(k):
            f, no = pre.where[k]
            raise ConfigError(f"{k}: gcodeplan's Marlin model runs cartesian, COREXY and COREXZ machines only", f, no)
    return pre, main_path, adv, adv_text is not None


def _scalar(pre: _Pre, name: str, lo_ok: bool = False) -> float:
    """``name``'s value, > 0 (>= 0 with ``lo_ok``)."""
    v = _number(pre, name)
    if not (v >= 0 if lo_ok else v > 0):
        f, no = pre.where[name]
        raise ConfigError(f"{name} must be {'>= 0' if lo_ok else '> 0'}, got {v:g}", f, no)
    return v


def _per_axis(pre: _Pre, axes: dict, notes: list[str], main_path: str, name: str, attr: str, what: str) -> None:
    """A brace list { X, Y, Z, E… } into each axis's ``attr``; the preset's values kept when it is not
    defined; one extruder modelled (E0's value)."""
    if name not in pre.values:
        _note(pre, notes, main_path, f"{name} not defined: the marlin preset's {what} kept")
        return
    vals = _array(pre, name)
    f, no = pre.where[name]
    for a, v in zip("xyze", vals[:4]):
        if not v > 0:
            raise ConfigError(f"{name} ({what}) {a.upper()} must be > 0, got {v:g}", f, no)
        axes[a] = replace(axes[a], **{attr: v})
    if len(vals) > 4 and any(v != vals[3] for v in vals[4:]):
        _note(pre, notes, main_path,
              f"{name}: values for {len(vals) - 3} extruders; gcodeplan models one, E0's {vals[3]:g} taken", name)


def _movement_settings(pre: _Pre, axes: dict, top: dict, notes: list[str], main_path: str) -> None:
    """Configuration.h's "Movement Settings": steps/mm, max feedrates (mm/s), max accelerations (mm/s²) per
    axis; the print, retract and travel accelerations (mm/s², M204 P/R/T)."""
    _per_axis(pre, axes, notes, main_path, "DEFAULT_AXIS_STEPS_PER_UNIT", "steps_per_mm", "steps/mm")
    _per_axis(pre, axes, notes, main_path, "DEFAULT_MAX_FEEDRATE", "max_velocity", "max feedrate mm/s")
    _per_axis(pre, axes, notes, main_path, "DEFAULT_MAX_ACCELERATION", "max_accel", "max acceleration mm/s²")
    for name, key in (("DEFAULT_ACCELERATION", "accel_print"), ("DEFAULT_RETRACT_ACCELERATION", "accel_retract"),
                      ("DEFAULT_TRAVEL_ACCELERATION", "accel_travel")):
        if name in pre.values:
            top[key] = _scalar(pre, name)
    if "accel_print" in top:
        top["max_accel"] = top["accel_print"]          # the preset's rule: max_accel is M204 P


def _junction_settings(pre: _Pre, axes: dict, top: dict, notes: list[str], main_path: str) -> None:
    """CLASSIC_JERK's per-axis jerks (mm/s) or junction deviation (mm), E's jerk; S_CURVE_ACCELERATION."""
    if pre.enabled("CLASSIC_JERK"):
        top["junction_policy"] = "classic-jerk"
        for a in "XYZ":
            name = f"DEFAULT_{a}JERK"
            if name in pre.values:
                axes[a.lower()] = replace(axes[a.lower()], jerk=_scalar(pre, name, lo_ok=True))
            else:
                _note(pre, notes, main_path,
                      f"CLASSIC_JERK on without {name}: the preset's {axes[a.lower()].jerk:g} mm/s kept", "CLASSIC_JERK")
    else:
        top["junction_policy"] = "junction-deviation"
        top["junction_deviation"] = _scalar(pre, "JUNCTION_DEVIATION_MM", lo_ok=True) \
            if "JUNCTION_DEVIATION_MM" in pre.values else 0.013
        if not pre.enabled("JD_HANDLE_SMALL_SEGMENTS"):
            _note(pre, notes, main_path,
                  "JD_HANDLE_SMALL_SEGMENTS off: the model runs junction deviation with it on (Marlin's default); "
                  "junctions of short segments on curves may differ", "JD_HANDLE_SMALL_SEGMENTS")
    if "DEFAULT_EJERK" in pre.values:
        axes["e"] = replace(axes["e"], jerk=_scalar(pre, "DEFAULT_EJERK", lo_ok=True))
    top["acceleration_profile"] = "s-curve" if pre.enabled("S_CURVE_ACCELERATION") else "trapezoid"


def _lin_advance_settings(pre: _Pre, top: dict, notes: list[str], main_path: str) -> None:
    """LIN_ADVANCE's K (s; 0 when off or not given)."""
    if pre.enabled("LIN_ADVANCE"):
        kname = "ADVANCE_K" if "ADVANCE_K" in pre.values else "LIN_ADVANCE_K"
        if kname not in pre.values:
            _note(pre, notes, main_path, "LIN_ADVANCE on without ADVANCE_K: K = 0 (no advance until M900 K)",
                  "LIN_ADVANCE")
            top["pressure_advance"] = 0.0
        else:
            src = pre.values[kname].strip()
            k = _array(pre, kname)[0] if src.startswith("{") else _scalar(pre, kname, lo_ok=True)
            top["pressure_advance"] = k
    else:
        top["pressure_advance"] = 0.0


def _arc_settings(pre: _Pre, top: dict, notes: list[str], main_path: str):
    """ARC_SUPPORT's segment rule (G2_G3.cpp's settings, mm and segments/s) as MarlinArcSettings."""
    from ..gcode.arcs_marlin import MarlinArcSettings

    if not pre.enabled("ARC_SUPPORT"):
        _note(pre, notes, main_path,
              "ARC_SUPPORT off: this build ignores G2/G3 (unknown command); gcodeplan refuses a program that has "
              "them", "ARC_SUPPORT")
        return MarlinArcSettings(enabled=False)
    mx = mn = None
    if "MAX_ARC_SEGMENT_MM" in pre.values:
        mx = _scalar(pre, "MAX_ARC_SEGMENT_MM")
    if "MIN_ARC_SEGMENT_MM" in pre.values:
        mn = _scalar(pre, "MIN_ARC_SEGMENT_MM")
    if mx is None and mn is None and "MM_PER_ARC_SEGMENT" in pre.values:
        mx = mn = _scalar(pre, "MM_PER_ARC_SEGMENT")     # Marlin before 2.0.9: one segment length
    # G2_G3.cpp: a missing bound takes the other's value
    mx = mx if mx is not None else (mn if mn is not None else 1.0)
    mn = mn if mn is not None else mx
    arcs = MarlinArcSettings(
        min_segment_mm=mn, max_segment_mm=mx,
        min_circle_segments=(int(_scalar(pre, "MIN_CIRCLE_SEGMENTS")) if "MIN_CIRCLE_SEGMENTS" in pre.values
                             else 72),
        segments_per_sec=(_scalar(pre, "ARC_SEGMENTS_PER_SEC", lo_ok=True) if pre.enabled("ARC_SEGMENTS_PER_SEC")
                          else 0.0),
        n_arc_correction=(max(1, int(_number(pre, "N_ARC_CORRECTION"))) if "N_ARC_CORRECTION" in pre.values
                          else 25),
        p_circles=pre.enabled("ARC_P_CIRCLES"))
    top["arc_resolution"] = mx
    if "ARC_SEGMENTS_PER_R" in pre.values:
        _note(pre, notes, main_path,
              "ARC_SEGMENTS_PER_R: not a Marlin 2.1.2 setting; the segment length rule is MIN/MAX_ARC_SEGMENT_MM",
              "ARC_SEGMENTS_PER_R")
    return arcs


def _block_buffer(pre: _Pre, main_path: str) -> int:
    """BLOCK_BUFFER_SIZE (Configuration_adv.h; Marlin's SanityCheck.h wants a power of 2): the Marlin model's
    planner ring. A value the firmware would not build is an error naming the line."""
    if "BLOCK_BUFFER_SIZE" not in pre.values:
        return 16
    from .fields import rule_block_buffer

    v = _number(pre, "BLOCK_BUFFER_SIZE")
    problem = rule_block_buffer(v)
    if problem:
        f, no = pre.where.get("BLOCK_BUFFER_SIZE", (main_path, None))
        raise ConfigError(f"BLOCK_BUFFER_SIZE {v:g}: {problem}", f, no)
    return int(v)


def _fixed_and_unmodelled(pre: _Pre, notes: list[str], main_path: str) -> None:
    """Warnings for the settings the model runs at one value (FIXED, SLOWDOWN), the minimum feedrates (M205
    S/T, program settings here) and the features it does not model (UNMODELLED)."""
    for name, (want, what) in FIXED.items():
        if name in pre.values:
            v = _number(pre, name)
            if v != want:
                _note(pre, notes, main_path,
                      f"{name} {v:g} ({what}): the marlin-2.1.2 model runs Marlin's default {want:g}; the times "
                      "are those of a build with the default", name)
    if not pre.enabled("SLOWDOWN"):
        _note(pre, notes, main_path,
              "SLOWDOWN off: the marlin-2.1.2 model slows short segments when the buffer runs low (Marlin's "
              "default); a build without it plans those faster", "SLOWDOWN")
    for name, what in (("DEFAULT_MINIMUMFEEDRATE", "minimum print feedrate, M205 S"),
                       ("DEFAULT_MINTRAVELFEEDRATE", "minimum travel feedrate, M205 T")):
        if name in pre.values and _number(pre, name) > 0:
            v = _number(pre, name)
            letter = "S" if "MINIMUMFEED" in name else "T"
            _note(pre, notes, main_path,
                  f"{name} {v:g} ({what}) is not a machine setting in gcodeplan: put 'M205 {letter}{v:g}' at the "
                  "top of the program for it to count", name)
    for name, what in UNMODELLED.items():
        if what and pre.enabled(name):
            _note(pre, notes, main_path,
                  f"{name} on: {what} is not modelled by the marlin-2.1.2 model; its times are those of a build "
                  "without it", name)


def _build_switches(pre: _Pre, notes: list[str], main_path: str) -> str:
    """The switches that add G codes (marlin_build.py), as the machine's ``marlin_build``: those gcodeplan
    models run as Marlin runs them; the others are named in a warning, and a program using their codes is
    refused at its line."""
    from ..marlin_build import MARLIN_BUILD_OPTIONS, UNMODELLED

    on = [name for name in MARLIN_BUILD_OPTIONS if pre.enabled(name)]
    for name in on:
        if name in UNMODELLED:
            codes = ", ".join(f"G{g}" for g in UNMODELLED[name][0])
            _note(pre, notes, main_path, f"{name} on: this build runs {codes}; {UNMODELLED[name][1]}: gcodeplan "
                  "refuses a program that has them", name)
    return " ".join(on)


def _fwretract_settings(pre: _Pre, top: dict, notes: list[str], main_path: str) -> None:
    """FWRETRACT's G10/G11 as ``[firmware_retraction]`` (feature/fwretract.cpp): G10 draws RETRACT_LENGTH mm back at
    RETRACT_FEEDRATE mm/s, G11 pushes that length plus RETRACT_RECOVER_LENGTH mm at RETRACT_RECOVER_FEEDRATE mm/s
    (Marlin's shipped 3, 45, 0, 8 when not given). Without FWRETRACT the build has no G10/G11 ("Unknown command"):
    the length stays 0, so they move nothing."""
    if not pre.enabled("FWRETRACT"):
        return
    for name, key, default, lo_ok in (("RETRACT_LENGTH", "retract_length", 3.0, True),
                                      ("RETRACT_FEEDRATE", "retract_speed", 45.0, False),
                                      ("RETRACT_RECOVER_FEEDRATE", "unretract_speed", 8.0, False)):
        top[key] = _scalar(pre, name, lo_ok=lo_ok) if name in pre.values else default
    extra = _number(pre, "RETRACT_RECOVER_LENGTH") if "RETRACT_RECOVER_LENGTH" in pre.values else 0.0
    if extra < 0:
        _note(pre, notes, main_path, f"RETRACT_RECOVER_LENGTH {extra:g} mm: gcodeplan recovers at least the "
              "retracted length (unretract_extra_length >= 0): 0 taken", "RETRACT_RECOVER_LENGTH")
    top["unretract_extra_length"] = max(extra, 0.0)
    if "RETRACT_ZRAISE" in pre.values and _number(pre, "RETRACT_ZRAISE") > 0:
        _note(pre, notes, main_path, f"RETRACT_ZRAISE {_number(pre, 'RETRACT_ZRAISE'):g} mm: the Z hop of G10/G11 is "
              "not modelled (the E moves are)", "RETRACT_ZRAISE")


def _software_endstops(pre: _Pre, axes: dict) -> None:
    """X/Y/Z_MIN_POS / _MAX_POS (mm) as each axis's travel when the software endstops are on (gcodeplan
    refuses a move beyond them)."""
    for a in "xyz":
        lo_name, hi_name = f"{a.upper()}_MIN_POS", f"{a.upper()}_MAX_POS"
        lo = hi = None
        try:
            if lo_name in pre.values and pre.enabled("MIN_SOFTWARE_ENDSTOPS"):
                lo = _number(pre, lo_name)
            if hi_name in pre.values and pre.enabled("MAX_SOFTWARE_ENDSTOPS"):
                hi = _number(pre, hi_name)
        except ConfigError:
            lo = hi = None              # an expression this reader cannot evaluate: no bound, rather than a wrong one
        axes[a] = replace(axes[a], position_min=-math.inf if lo is None else lo,
                          position_max=math.inf if hi is None else hi)
        if not axes[a].position_max > axes[a].position_min:
            axes[a] = replace(axes[a], position_min=-math.inf, position_max=math.inf)
