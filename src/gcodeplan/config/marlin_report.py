"""A machine from Marlin's ``M503`` settings report (what a host's terminal shows for ``M503``, saved as a
file): the ``marlin`` preset with the report's steps/mm (M92), maximum feedrates (M203), maximum
accelerations (M201), default accelerations (M204 P R T), jerks or junction deviation (M205) and linear
advance (M900 K), run on the ``marlin-2.1.2`` firmware model (planner/marlin.py).

Recognised by content (:func:`is_marlin_report`): every meaningful line is a G/M setting command, with or
without Marlin's ``echo:`` prefix (and a host's ``Recv:``), between ``; comment`` lines such as
``echo:; Steps per unit:`` and ``ok``; at least two of M92/M201/M203/M204/M205 appear; no motion command.

A build prints ``M205 … J<mm>`` when it plans junctions by junction deviation (CLASSIC_JERK off) and
``M205 … X Y Z E`` jerks when it uses classic jerk (Marlin's ``M503``, ``gcode/config/M200-M205.cpp``); the
machine's junction policy follows. Settings that change the time of a program and that the model does not
run are refused or warned about by name; the others (temperatures, PID, probe offsets, currents …) do not
change the time.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import replace

from ..errors import ConfigError

# "echo:", "Recv: echo:" (OctoPrint's terminal); "//" action lines and "Send:" lines are not settings
_PREFIX = re.compile(r"^(?:recv:\s*)?(?:echo:\s*)?", re.IGNORECASE)
_COMMAND = re.compile(r"^([GM])(\d+)((?:\s+[A-Z][^\s;]*)*)\s*(?:;.*)?$", re.IGNORECASE)
_WORD = re.compile(r"([A-Z])([^\s;]*)", re.IGNORECASE)
_LOOKS_LIKE_COMMAND = re.compile(r"^[GM]\d+(\s|;|$)", re.IGNORECASE)
_PASS = re.compile(r"^(ok\b.*|;.*|//.*|send:.*|m503\s*)?$", re.IGNORECASE)

#: the settings the machine is built from
CORE = {"M92", "M201", "M203", "M204", "M205"}
#: report lines that do not change the time of a program: units of temperature, filament loading,
#: home/probe/hotend offsets, temperatures and PID/MPC, driver currents/modes/sensorless homing,
#: power-loss recovery, runout sensor, material presets, servo angles, LCD, serial, fans, homing feedrates
NO_TIMING = {"M149", "M145", "M206", "M218", "M281", "M301", "M303", "M304", "M306", "M309", "M413", "M412",
             "M569", "M575", "M600", "M603", "M851", "M906", "M911", "M912", "M913", "M914", "M710", "M250",
             "M256", "M217", "M210", "M222", "M192", "M355", "M540", "M907"}
#: motion commands: a file with one is a program, not a report
_MOTION = {"G0", "G1", "G2", "G3", "G4", "G5", "G28", "G29", "G92"}


def _strip(line: str) -> tuple[str, bool]:
    """The line without its ``Recv:``/``echo:`` prefix, and whether it had ``echo:`` (a firmware message)."""
    s = line.strip()
    m = _PREFIX.match(s)
    return s[m.end():].strip(), "echo:" in m.group(0).lower()


def _commands(text: str):
    """(line number, code, {letter: text}, stripped line) of each command line; None entries for lines that
    are neither a command nor passable (the caller decides)."""
    for no, line in enumerate(text.splitlines(), 1):
        s, echo = _strip(line)
        if _PASS.match(s):
            continue
        m = _COMMAND.match(s)
        if not m:
            # "echo:Active Mesh Slot: 0" and such are the firmware's messages; a command line is not
            if not echo or _LOOKS_LIKE_COMMAND.match(s):
                yield no, None, None, s
            continue
        code = f"{m.group(1).upper()}{int(m.group(2))}"
        words = {w.group(1).upper(): w.group(2) for w in _WORD.finditer(m.group(3) or "")}
        yield no, code, words, s


def is_marlin_report(path: str) -> bool:
    """True when the file is an ``M503`` report (see the module docstring)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
        text = head.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return False
    seen = set()
    for _no, code, _words, _s in _commands(text):
        # a motion command makes a program (G29 W … lines are the mesh of a levelling report)
        if code is None or code in _MOTION and code != "G29":
            return False
        seen.add(code)
    return len(seen & CORE) >= 2


def _number(path: str, no: int, code: str, letter: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ConfigError(f"{code} {letter}: needs a number, got {text!r}", path, no) from None
    if not math.isfinite(v):
        raise ConfigError(f"{code} {letter} must be a finite number", path, no)
    return v


def _m204_accelerations(path: str, no: int, words: dict, top: dict) -> None:
    """``M204 P R T`` (print, retract, travel acceleration mm/s²; ``S`` before Marlin 1.1: print and travel) into
    the machine's top-level settings ``top``."""
    names = {"P": "accel_print", "R": "accel_retract", "T": "accel_travel"}
    for letter, text_v in words.items():
        v = _number(path, no, "M204", letter, text_v)
        if not v > 0:
            raise ConfigError(f"M204 {letter} must be > 0, got {v:g}", path, no)
        if letter == "S":          # before 1.1: S = printing and travel
            top.setdefault("accel_print", v)
            top.setdefault("accel_travel", v)
        elif letter in names:
            top[names[letter]] = v
        else:
            raise ConfigError(f"M204 {letter}: not a Marlin acceleration (P R T)", path, no)


def _m205_advanced(path: str, no: int, words: dict, axes: dict, top: dict, warn):
    """``M205`` (Marlin's advanced settings): X Y Z E jerks (mm/s) into ``axes``, J junction deviation (mm) into
    ``top``; B, S, T warn when they differ from what the model runs. Returns (line if an X/Y/Z jerk was set,
    line if J was set), None for each not set."""
    jerk_seen = jd_seen = None
    for letter, text_v in words.items():
        v = _number(path, no, "M205", letter, text_v)
        if v < 0:
            raise ConfigError(f"M205 {letter} must be >= 0, got {v:g}", path, no)
        if letter in "XYZE":
            axes[letter.lower()] = replace(axes[letter.lower()], jerk=v)
            if letter != "E":
                jerk_seen = no
        elif letter == "J":
            top["junction_deviation"] = v
            jd_seen = no
        elif letter == "B":
            if v != 20000:
                warn(no, f"M205 B{v:g} (minimum segment time µs): the marlin-2.1.2 model runs "
                         "Marlin's default 20000 µs")
        elif letter in "ST":
            if v > 0:
                what = "minimum print feedrate" if letter == "S" else "minimum travel feedrate"
                warn(no, f"M205 {letter}{v:g} ({what}) is not a machine setting in gcodeplan: put "
                         f"'M205 {letter}{v:g}' at the top of the program for it to count")
        else:
            raise ConfigError(f"M205 {letter}: not a Marlin M205 setting (B S T J X Y Z E)", path, no)
    return jerk_seen, jd_seen


def load_marlin_report(path: str):
    """The :class:`~gcodeplan.machine.Machine` of an ``M503`` report (see the module docstring)."""
    from .fields import validate
    from .toml import load_preset, read_text

    text = read_text(path)
    machine = load_preset("marlin")
    axes = dict(machine.axes)
    top: dict = {}
    jerk_seen = jd_seen = None

    def warn(no: int, msg: str) -> None:
        warnings.warn(f"{path}:{no}: {msg}", stacklevel=3)

    def set_axis(no, code, words, attr, what, positive=True):
        tool = words.get("T")
        if tool is not None and _number(path, no, code, "T", tool) != 0:
            warn(no, f"{code} T{tool}: a second extruder's {what} ignored (gcodeplan models one extruder)")
            return
        for letter in "XYZE":
            if letter in words:
                v = _number(path, no, code, letter, words[letter])
                if positive and not v > 0 or not positive and v < 0:
                    raise ConfigError(f"{code} {letter} ({what}) must be {'> 0' if positive else '>= 0'}, "
                                      f"got {v:g}", path, no)
                axes[letter.lower()] = replace(axes[letter.lower()], **{attr: v})

    for no, code, words, s in _commands(text):
        if code is None:
            raise ConfigError(f"not an M503 report line (a G/M setting command): {s[:40]!r}", path, no)
        if code == "M92":
            set_axis(no, code, words, "steps_per_mm", "steps/mm")
        elif code == "M203":
            set_axis(no, code, words, "max_velocity", "max feedrate mm/s")
        elif code == "M201":
            set_axis(no, code, words, "max_accel", "max acceleration mm/s²")
        elif code == "M204":
            _m204_accelerations(path, no, words, top)
        elif code == "M205":
            jerk, jd = _m205_advanced(path, no, words, axes, top, warn)
            jerk_seen = jerk if jerk is not None else jerk_seen
            jd_seen = jd if jd is not None else jd_seen
        elif code == "M900":
            if words.get("T") is not None and _number(path, no, code, "T", words["T"]) != 0:
                warn(no, "M900 T: a second extruder's linear advance ignored (gcodeplan models one extruder)")
                continue
            if "K" in words:
                k = _number(path, no, code, "K", words["K"])
                if k < 0:
                    raise ConfigError(f"M900 K must be >= 0, got {k:g}", path, no)
                top["pressure_advance"] = k       # LIN_ADVANCE K (mm per mm/s), modelled by marlin-2.1.2
            for letter in words:
                if letter not in "KT":
                    warn(no, f"M900 {letter}: not modelled (only K, the linear advance factor)")
        elif code == "M593":
            freq = words.get("F")
            if freq is not None and _number(path, no, code, "F", freq) > 0:
                warn(no, f"M593 (input shaping {s}): not modelled by the marlin-2.1.2 model; its step times "
                         "and the total are those of an unshaped build")
        elif code == "M200":
            # Marlin 2 prints "M200 S0 D1.75": S1 = volumetric extrusion on at start-up (E in mm³)
            if "S" in words and _number(path, no, code, "S", words["S"]) != 0:
                warn(no, "M200 S1 (volumetric extrusion on): not a machine setting in gcodeplan; E is read as "
                         "mm³ only after an M200 D in the program")
        elif code in ("G21", "G20"):
            if code == "G20":
                raise ConfigError("G20: the report is in inches; gcodeplan reads Marlin's settings in mm "
                                  "(send G21 before M503)", path, no)
        elif code == "M420":
            if "S" in words and _number(path, no, code, "S", words["S"]) != 0:
                warn(no, "M420 S1 (bed levelling on): the Z corrections of the mesh are not modelled")
        elif code == "G29":
            pass                              # mesh points of the levelling report (M420 warns)
        elif code == "M425":
            if any(k in words and _number(path, no, code, k, words[k]) > 0 for k in "XYZ") and not (
                    "F" in words and _number(path, no, code, "F", words["F"]) == 0):
                warn(no, "M425 (backlash compensation): the extra correction steps are not modelled")
        elif code in ("M207", "M208", "M209"):
            warn(no, f"{code} (firmware retraction): not read from a report; set [firmware_retraction] in a "
                     "machine TOML (docs/machine.md) if the program uses G10/G11")
        elif code in ("M665", "M666"):
            raise ConfigError(f"{code}: a delta printer's geometry; gcodeplan's Marlin model is cartesian", path, no)
        elif code in NO_TIMING:
            pass
        else:
            warn(no, f"{code}: not a setting gcodeplan knows; ignored (it may change the time)")
    if jd_seen is not None and jerk_seen is not None:
        raise ConfigError("M205 gives both J (junction deviation) and X/Y/Z jerks: a Marlin build has one or "
                          "the other", path, jd_seen)
    if jd_seen is not None:
        top["junction_policy"] = "junction-deviation"
    elif jerk_seen is not None:
        top["junction_policy"] = "classic-jerk"
    if "accel_print" in top:
        top["max_accel"] = top["accel_print"]     # the preset's rule: max_accel is M204 P
    machine = replace(machine, axes=axes, name=f"marlin M503 ({path})", **top)
    validate(machine, path)                       # the limits every machine obeys (absurdly small values …)
    return machine
