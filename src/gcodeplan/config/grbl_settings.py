"""A machine from grbl's ``$$`` settings report (the text a sender shows for ``$$``, or a file of ``$N=value``
lines): the ``grbl`` preset with the report's steps/mm, rates, accelerations, junction deviation, arc tolerance
and travel, run on the ``grbl-1.1`` firmware model (planner/grbl.py).

Recognised by content (:func:`is_grbl_settings`): every meaningful line is ``$N=value``, optionally followed by
grbl 0.9's ``(comment)``; ``ok`` lines, blank lines and ``;``/``(`` comment lines are passed over. ``$1`` is the
stepper idle delay, ``$32`` laser mode (``grbl_laser_mode``); settings that change the time of a program and that
the model does not run are refused by name; the others (pulse width, pin inversions, reports, homing, the
spindle's rpm range) do not change the time.
"""
from __future__ import annotations

import math
import re
from dataclasses import replace

from ..errors import ConfigError

_SETTING = re.compile(r"^\$(\d+)\s*=\s*([-+]?[0-9]*\.?[0-9]+)\s*(\(.*\))?\s*$")
_PASS = re.compile(r"^(ok|;.*|\(.*\)|\[.*\])?$", re.IGNORECASE)

# $N: (what, machine attribute path, factor from grbl's unit to gcodeplan's)
TIMING = {
    100: ("x steps/mm", ("x", "steps_per_mm"), 1.0), 101: ("y steps/mm", ("y", "steps_per_mm"), 1.0),
    102: ("z steps/mm", ("z", "steps_per_mm"), 1.0),
    110: ("x max rate mm/min", ("x", "max_velocity"), 1 / 60), 111: ("y max rate mm/min", ("y", "max_velocity"), 1 / 60),
    112: ("z max rate mm/min", ("z", "max_velocity"), 1 / 60),
    120: ("x acceleration mm/s²", ("x", "max_accel"), 1.0), 121: ("y acceleration mm/s²", ("y", "max_accel"), 1.0),
    122: ("z acceleration mm/s²", ("z", "max_accel"), 1.0),
    11: ("junction deviation mm", (None, "junction_deviation"), 1.0),
    12: ("arc tolerance mm", (None, "arc_tolerance"), 1.0),
}
TRAVEL = {130: "x", 131: "y", 132: "z"}
# no effect on the time of a program
NO_TIMING = {0, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 24, 25, 26, 27, 30, 31}


def is_grbl_settings(path: str) -> bool:
    """True when the file is a ``$$`` report: at least three ``$N=value`` lines and nothing but them, ``ok``
    and comments."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except OSError:
        return False
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError:
        return False
    n = 0
    for line in text.splitlines():
        s = line.strip()
        if _SETTING.match(s):
            n += 1
        elif not _PASS.match(s):
            return False
    return n >= 3


def load_grbl_settings(path: str):
    """The :class:`~gcodeplan.machine.Machine` of a ``$$`` report (see the module docstring)."""
    from .toml import load_preset, read_text

    text = read_text(path)
    values: dict[int, float] = {}
    where: dict[int, int] = {}
    for no, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        m = _SETTING.match(s)
        if not m:
            if _PASS.match(s):
                continue
            raise ConfigError(f"line {no}: not a grbl setting ($N=value): {s[:40]!r}", path)
        key, value = int(m.group(1)), float(m.group(2))
        # grbl keeps its settings as floats: past 3.4e38 a value is inf there, under 1.4e-45 it is 0
        if not math.isfinite(value) or abs(value) > 3.4e38:
            raise ConfigError(f"line {no}: ${key}={m.group(2)[:20]} is beyond grbl's float range (3.4e38)", path)
        values[key] = value
        where[key] = no
    machine = load_preset("grbl")
    axes = dict(machine.axes)
    top = {}
    for key, value in values.items():
        if key in TIMING:
            what, (axis, attr), factor = TIMING[key]
            v = value * factor
            if not v > 0 and key not in (11,):
                raise ConfigError(f"${key} ({what}) must be > 0, got {value:g}", path)
            if key == 11 and v < 0:
                raise ConfigError(f"$11 (junction deviation mm) must be >= 0, got {value:g}", path)
            if axis is None:
                top[attr] = v
            else:
                axes[axis] = replace(axes[axis], **{attr: v})
        elif key in TRAVEL:
            # travel bounds a move only with soft limits on ($20=1); it is a length: the work zero may lie
            # anywhere in it (as the grbl preset says)
            travel = abs(value) if values.get(20, 0) == 1 else math.inf
            axes[TRAVEL[key]] = replace(axes[TRAVEL[key]], position_min=-travel, position_max=travel)
        elif key == 1:
            top["grbl_idle_lock_ms"] = value
        elif key == 32:
            # settings.c: any value that truncates to non-zero turns laser mode on (gcode.c: no stop at an S
            # change on a motion line; gcode/commands_state.py _grbl_syncs)
            top["grbl_laser_mode"] = 1 if math.trunc(value) != 0 else 0
        elif key in NO_TIMING:
            pass
        else:
            raise ConfigError(f"${key} is not a grbl 1.1 setting gcodeplan knows", path)
    for key, value in values.items():
        if key in TIMING and 0 < abs(value) < 1.4e-45:
            raise ConfigError(f"line {where[key]}: ${key} ({TIMING[key][0]}) is 0 in grbl's float (a float holds "
                              f"nothing under 1.4e-45), got {value:g}", path)
    idle = top.pop("grbl_idle_lock_ms", None)
    machine = replace(machine, axes=axes, firmware="grbl-1.1", name=f"grbl $$ ({path})", **top)
    if idle is not None:
        if not (0 <= idle <= 255):
            raise ConfigError(f"$1 (step idle delay ms) must be 0…255, got {idle:g}", path)
        machine = replace(machine, grbl_idle_lock_ms=idle)
    from .fields import validate

    validate(machine, path)              # the limits every machine obeys (absurdly small or large values …)
    return machine
