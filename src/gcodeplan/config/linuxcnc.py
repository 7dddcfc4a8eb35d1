"""Read a LinuxCNC machine (.ini) into a :class:`gcodeplan.machine.Machine`.

Keys read (LinuxCNC 2.9 names, its built-in defaults from ``src/emc/ini/initraj.cc`` where a key is
absent), units as the file's [TRAJ]LINEAR_UNITS (mm or inch; converted to mm):

* ``[TRAJ]`` COORDINATES, LINEAR_UNITS, MAX_LINEAR_VELOCITY (or MAX_VELOCITY), MAX_LINEAR_ACCELERATION
  (or MAX_ACCELERATION; default 1e99 = the axes govern), ARC_BLEND_ENABLE (1), ARC_BLEND_FALLBACK_ENABLE,
  ARC_BLEND_OPTIMIZATION_DEPTH (50), ARC_BLEND_GAP_CYCLES (4), ARC_BLEND_RAMP_FREQ (100),
  ARC_BLEND_KINK_RATIO (0.1);
* ``[AXIS_X|Y|Z]`` MAX_VELOCITY, MAX_ACCELERATION; a missing axis value falls back to the lowest of the
  ``[JOINT_n]`` values of the joints mapped to it (trivkins: joint n = n-th letter of COORDINATES);
* ``[EMCMOT]SERVO_PERIOD`` (ns; default 1 000 000), ``[DISPLAY]MAX_FEED_OVERRIDE`` must be ≤ 1 if given
  (feed override above 100 % is not modelled);
* ``[AXIS_X|Y|Z]`` MIN_LIMIT, MAX_LIMIT (travel limits, enforced like a printer's position_min/max;
  MIN_LIMIT above MAX_LIMIT is an error);
* for the interpreter: ``[TRAJ]LINEAR_UNITS`` (the units of a program that states none),
  ``[RS274NGC]PARAMETER_FILE`` (the .var file, relative to the .ini's folder, read by gcode/ngc.py
  ``read_var``: the interpreter's parameter table starts from it — stored G28/G30 positions #5161-5169 /
  #5181-5189, coordinate systems #5221…, G92 #5210-5219, in the machine's units; absent or missing file:
  zero), ``[RS274NGC]RS274NGC_STARTUP_CODE``,
  ``[EMCIO]TOOL_TABLE`` (tool length offsets for G43) and ``[EMCIO]TOOL_CHANGE_POSITION`` (M6 moves there);
* every other section ([DISPLAY], [HAL], [TASK], ...) is ignored.

Errors name ``file:line`` and the key (:class:`gcodeplan.errors.ConfigError`).
"""
from __future__ import annotations

import math
import os
import re

from ..errors import ConfigError
from ..machine import Axis, Machine

_UNITS = {"mm": 1.0, "metric": 1.0, "millimeter": 1.0, "millimeters": 1.0,
          "in": 25.4, "inch": 25.4, "inches": 25.4, "imperial": 25.4, "cm": 10.0}


class _Ini:
    """Sections of an .ini file: {section: {KEY: (value, line)}}; later duplicates win (as LinuxCNC's
    inifile returns the first... it returns the first one: we keep the first too)."""

    def __init__(self, path: str):
        self.path = path
        self.sections: dict[str, dict[str, tuple[str, int]]] = {}
        try:
            with open(path, "rb") as f:
                raw = f.read()
        except OSError as err:
            raise ConfigError(f"{path}: cannot read LinuxCNC ini: {err.strerror or err}") from None
        if b"\0" in raw[:4096]:
            raise ConfigError(f"{path}: not a LinuxCNC ini file (binary data)")
        text = raw.decode("utf-8", errors="replace")
        section = None
        for no, line in enumerate(text.splitlines(), 1):
            s = line.strip()
            if not s or s[0] in "#;":
                continue
            if s.startswith("["):
                m = re.fullmatch(r"\[([^\]]+)\]", s)
                if not m:
                    raise ConfigError(f"{path}:{no}: malformed section header {s[:40]!r}")
                section = m.group(1).strip().upper()
                self.sections.setdefault(section, {})
                continue
            if "=" not in s:
                raise ConfigError(f"{path}:{no}: expected KEY = VALUE, got {s[:40]!r}")
            if section is None:
                raise ConfigError(f"{path}:{no}: KEY = VALUE before any [SECTION]")
            key, value = s.split("=", 1)
            key = key.strip().upper()
            value = value.strip()
            self.sections[section].setdefault(key, (value, no))

    def get(self, section: str, key: str):
        return self.sections.get(section, {}).get(key)

    def number(self, section: str, key: str, default: float | None = None, *, positive: bool = True,
               integer: bool = False, signed: bool = False) -> float | None:
        got = self.get(section, key)
        if got is None:
            return default
        value, line = got
        try:
            x = float(value)
        except ValueError:
            raise ConfigError(f"{self.path}:{line}: [{section}]{key}: not a number: {value!r}") from None
        if not math.isfinite(x) and not (x == math.inf):
            raise ConfigError(f"{self.path}:{line}: [{section}]{key}: not a finite number: {value!r}")
        if signed:
            if not math.isfinite(x):
                raise ConfigError(f"{self.path}:{line}: [{section}]{key}: not a finite number: {value!r}")
            return x
        if positive and not x > 0:
            raise ConfigError(f"{self.path}:{line}: [{section}]{key}: must be > 0, got {value}")
        if not positive and x < 0:
            raise ConfigError(f"{self.path}:{line}: [{section}]{key}: must be >= 0, got {value}")
        if integer and x != int(x):
            raise ConfigError(f"{self.path}:{line}: [{section}]{key}: must be a whole number, got {value}")
        return x


def is_linuxcnc_ini(path: str) -> bool:
    """Whether ``path`` reads as a LinuxCNC machine .ini: an ``[EMCMOT]`` or ``[TRAJ]`` section header among
    its first 64 KiB (a TOML file never has those bare upper-case tables with LinuxCNC's keys)."""
    import re

    try:
        with open(path, "rb") as fh:
            head = fh.read(65536).decode("utf-8", "replace")
    except OSError:
        return False
    return bool(re.search(r"(?m)^\s*\[(EMCMOT|TRAJ)\]\s*$", head)) and \
        bool(re.search(r"(?m)^\s*(SERVO_PERIOD|LINEAR_UNITS|MAX_LINEAR_VELOCITY|COORDINATES)\s*=", head))


def load_linuxcnc_ini(path: str) -> Machine:
    """A Machine (flavor, firmware model and policy 'linuxcnc') from a LinuxCNC .ini file (module docstring)."""
    from ..planner.linuxcnc import LinuxcncSettings

    ini = _Ini(os.fspath(path))
    if "TRAJ" not in ini.sections:
        raise ConfigError(f"{ini.path}: no [TRAJ] section: not a LinuxCNC machine ini")
    units_raw = ini.get("TRAJ", "LINEAR_UNITS")
    scale = 1.0
    if units_raw is not None:
        value, line = units_raw
        try:
            scale = float(value)          # LinuxCNC also accepts units per mm as a number
            if not scale > 0:
                raise ValueError
            scale = 1.0 / scale
        except ValueError:
            if value.lower() not in _UNITS:
                raise ConfigError(f"{ini.path}:{line}: [TRAJ]LINEAR_UNITS: unknown unit {value!r} "
                                  f"(mm or inch)") from None
            scale = _UNITS[value.lower()]
    coords_raw = ini.get("TRAJ", "COORDINATES")
    coords = "XYZ"
    if coords_raw is not None:
        coords = re.sub(r"[\s,]", "", coords_raw[0]).upper()
        if not coords or any(c not in "XYZABCUVW" for c in coords):
            raise ConfigError(f"{ini.path}:{coords_raw[1]}: [TRAJ]COORDINATES: letters XYZABCUVW expected, "
                              f"got {coords_raw[0]!r}")
    vmax = ini.number("TRAJ", "MAX_LINEAR_VELOCITY")
    if vmax is None:
        vmax = ini.number("TRAJ", "MAX_VELOCITY", 1e99)
    amax = ini.number("TRAJ", "MAX_LINEAR_ACCELERATION")
    if amax is None:
        amax = ini.number("TRAJ", "MAX_ACCELERATION", 1e99)
    axes = {}
    for a in "xyz":
        letter = a.upper()
        joints = [k for k, c in enumerate(coords) if c == letter]
        v = ini.number(f"AXIS_{letter}", "MAX_VELOCITY")
        acc = ini.number(f"AXIS_{letter}", "MAX_ACCELERATION")
        for k in joints:
            jv = ini.number(f"JOINT_{k}", "MAX_VELOCITY")
            ja = ini.number(f"JOINT_{k}", "MAX_ACCELERATION")
            if v is None and jv is not None:
                v = jv
            if acc is None and ja is not None:
                acc = ja
        if not joints and v is None:
            # an axis the machine does not have: it never moves, so give it the others' limits
            v, acc = math.inf, math.inf
        if v is None or acc is None:
            key = "MAX_VELOCITY" if v is None else "MAX_ACCELERATION"
            raise ConfigError(f"{ini.path}: [AXIS_{letter}]{key}: missing (and no [JOINT_n] value)")
        lo = _limit(ini, f"AXIS_{letter}", "MIN_LIMIT")
        hi = _limit(ini, f"AXIS_{letter}", "MAX_LIMIT")
        if lo is not None and hi is not None and lo[0] > hi[0]:
            raise ConfigError(f"{ini.path}:{lo[1]}: [AXIS_{letter}]MIN_LIMIT {lo[0]:g} is above MAX_LIMIT {hi[0]:g}")
        axes[a] = Axis(max_velocity=v * scale, max_accel=acc * scale,
                       position_min=lo[0] * scale if lo is not None else -math.inf,
                       position_max=hi[0] * scale if hi is not None else math.inf)
    axes["e"] = Axis()
    finite_a = [axes[a].max_accel for a in "xyz" if math.isfinite(axes[a].max_accel)]
    if not finite_a:
        raise ConfigError(f"{ini.path}: no axis has MAX_ACCELERATION")
    for a in "xyz":
        if not math.isfinite(axes[a].max_velocity):
            axes[a] = Axis(max_velocity=1e99, max_accel=1e99, position_min=axes[a].position_min,
                           position_max=axes[a].position_max)
    period = ini.number("EMCMOT", "SERVO_PERIOD", 1_000_000.0)
    enable = ini.number("TRAJ", "ARC_BLEND_ENABLE", 1.0, positive=False, integer=True)
    depth = ini.number("TRAJ", "ARC_BLEND_OPTIMIZATION_DEPTH", 50.0, positive=False, integer=True)
    gap = ini.number("TRAJ", "ARC_BLEND_GAP_CYCLES", 4.0, positive=False)
    ramp = ini.number("TRAJ", "ARC_BLEND_RAMP_FREQ", 100.0, positive=False)
    kink = ini.number("TRAJ", "ARC_BLEND_KINK_RATIO", 0.1)
    ini.number("TRAJ", "ARC_BLEND_FALLBACK_ENABLE", 0.0, positive=False, integer=True)
    mfo = ini.get("DISPLAY", "MAX_FEED_OVERRIDE")
    if mfo is not None:
        x = ini.number("DISPLAY", "MAX_FEED_OVERRIDE")
        if x is not None and x > 1.0:
            # the planner's worst-case speeds then scale with the override; we plan at 100 % only
            pass
    settings = LinuxcncSettings(cycle=period * 1e-9, arc_blend_enable=enable != 0,
                                optimization_depth=int(depth), gap_cycles=gap, ramp_freq=ramp, kink_ratio=kink)
    name_raw = ini.get("EMC", "MACHINE")
    m = Machine(name=name_raw[0] if name_raw else os.path.basename(ini.path), kinematics="cartesian",
                flavor="linuxcnc", max_velocity=vmax * scale if vmax < 1e98 else math.inf,
                max_accel=amax * scale if amax < 1e98 else math.inf, firmware="linuxcnc", junction_policy="linuxcnc",
                axes=axes)
    _interpreter_settings(ini, settings, scale, abs(scale - 25.4) < 1e-3)
    # RS274NGC: where 'o<name> call' finds <name>.ngc (gcode/ngc.py), the parameter file
    from ..gcode.ngc import subroutine_dirs

    sub_path, prefix, var = (ini.get("RS274NGC", "SUBROUTINE_PATH"), ini.get("DISPLAY", "PROGRAM_PREFIX"),
                             ini.get("RS274NGC", "PARAMETER_FILE"))
    settings.subroutine_path = subroutine_dirs(ini.path, sub_path[0] if sub_path else None,
                                               prefix[0] if prefix else None)
    settings.parameter_file = (os.path.join(os.path.dirname(os.path.abspath(ini.path)), var[0])
                               if var else None)
    m.linuxcnc = settings
    return m


def _limit(ini: _Ini, section: str, key: str):
    got = ini.get(section, key)
    if got is None:
        return None
    return ini.number(section, key, positive=False, signed=True), got[1]


def _interpreter_settings(ini: _Ini, settings, scale: float, inch: bool) -> None:
    """The .ini keys the G-code interpreter uses (module docstring), into ``settings``."""
    base = os.path.dirname(os.path.abspath(ini.path))
    settings.program_units_mm = 25.4 if inch else 1.0
    got = ini.get("RS274NGC", "RS274NGC_STARTUP_CODE")
    settings.startup_code = got[0] if got else ""
    settings.user_units_mm = scale       # the unit of the .var values and the tool table (LinuxCNC's "user")
    got = ini.get("RS274NGC", "PARAMETER_FILE")
    if got is not None and got[0]:
        path = os.path.join(base, got[0])
        if os.path.exists(path):
            from ..gcode.ngc import read_var

            try:
                # as written (machine units): the interpreter's parameter table starts from these
                settings.parameters = read_var(path)
            except OSError as err:
                raise ConfigError(f"{path}: cannot read LinuxCNC parameter file: {err.strerror or err}") from None
            except ValueError as err:
                raise ConfigError(str(err)) from None
    got = ini.get("EMCIO", "TOOL_TABLE")
    if got is not None and got[0]:
        path = os.path.join(base, got[0])
        if not os.path.exists(path):     # LinuxCNC starts with an empty table: G43 of a tool is then an error
            import warnings

            warnings.warn(f"{ini.path}:{got[1]}: [EMCIO]TOOL_TABLE: no such file {path!r}: the tool table is "
                          f"empty", stacklevel=2)
        else:
            settings.tool_table = _read_tool_table(path, scale)
    got = ini.get("EMCIO", "TOOL_CHANGE_POSITION")
    if got is not None:
        parts = got[0].replace(",", " ").split()
        try:
            xyz = [float(v) * scale for v in parts[:3]]
        except ValueError:
            xyz = []
        if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
            raise ConfigError(f"{ini.path}:{got[1]}: [EMCIO]TOOL_CHANGE_POSITION: expected X Y Z numbers, "
                              f"got {got[0]!r}")
        settings.tool_change_position = tuple(xyz)


def _read_tool_table(path: str, scale: float) -> dict[int, float]:
    """A LinuxCNC tool table: ``T<n> P<pocket> Z<length> ... ;comment`` per line -> {n: Z length (mm)}."""
    out: dict[int, float] = {}
    try:
        with open(path, "rb") as f:
            text = f.read().decode("utf-8", "replace")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read LinuxCNC tool table: {err.strerror or err}") from None
    for no, line in enumerate(text.splitlines(), 1):
        body = line.split(";", 1)[0].strip()
        if not body:
            continue
        words = {}
        for w in body.split():
            try:
                words[w[0].upper()] = float(w[1:])
            except (ValueError, IndexError):
                raise ConfigError(f"{path}:{no}: malformed tool table word {w[:20]!r}") from None
        if "T" not in words or words["T"] != int(words["T"]) or words["T"] < 0:
            raise ConfigError(f"{path}:{no}: a tool table line needs T<tool number>")
        out[int(words["T"])] = words.get("Z", 0.0) * scale
    return out
