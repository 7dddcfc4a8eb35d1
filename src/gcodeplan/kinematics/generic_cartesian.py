"""Generic cartesian (Klipper's kinematics/generic_cartesian.py) as a plug-in.

Carriages ``[carriage NAME]`` each move along one axis (``axis: x|y|z``, with the rail's range);
steppers ``[stepper NAME]`` each drive a sum of carriages (``carriages: carriage_x+carriage_y``, ``-`` for a
negative one, optionally with a factor such as ``2*carriage_x``). A motor's position is that signed sum of axes
positions, so the machine is linear: its motors are stepped by the exact polynomial kernel through their
weights. Limits are cartesian's (per-axis ranges from the carriages, the Z-ratio rule). Klipper's dual
carriages and extra carriages are not modelled.

``machine.kinematics_params``: ``motors`` (name → [w_x, w_y, w_z]) and ``steps_per_mm`` (name → steps/mm),
in output order.
"""
from __future__ import annotations

import math
import re

from ..errors import ConfigError
from .plugin import Plugin, register

NAME = "generic_cartesian"
_TERM = re.compile(r"\s*([+-]?)\s*(?:(\d+(?:\.\d*)?|\.\d+)\s*\*\s*)?([A-Za-z_][A-Za-z0-9_]*)\s*")


class GenericCartesian(Plugin):
    """The machine's own motors from ``kinematics_params``."""

    def rails(self, machine, klipper_names: bool = False):
        kp = machine.kinematics_params
        motors = kp.get("motors")
        spm = kp.get("steps_per_mm")
        if not isinstance(motors, dict) or not motors or not isinstance(spm, dict):
            raise ConfigError("kinematics_params.motors / steps_per_mm: required by kinematics 'generic_cartesian' "
                              "(motor name → [w_x, w_y, w_z], motor name → steps/mm)")
        inner = Plugin({k: tuple(v) for k, v in motors.items()}, {k: float(spm[k]) for k in motors if k in spm})
        inner.name = NAME
        return inner.rails(machine, klipper_names)


def parse_carriages(text: str, carriages: dict[str, int], where: str) -> list[float]:
    """[w_x, w_y, w_z] of a ``carriages:`` value (ConfigError naming ``where`` when it is not one)."""
    w = [0.0, 0.0, 0.0]
    pos = 0
    text = text.strip()
    while pos < len(text):
        m = _TERM.match(text, pos)
        if m is None or (pos > 0 and not m.group(1)):
            raise ConfigError(f"{where}: cannot read {text!r} as a sum of carriages (carriage_x+carriage_y)")
        sign = -1.0 if m.group(1) == "-" else 1.0
        factor = float(m.group(2)) if m.group(2) else 1.0
        name = m.group(3)
        if name not in carriages:
            raise ConfigError(f"{where}: unknown carriage {name!r} (known: {', '.join(carriages)})")
        w[carriages[name]] += sign * factor
        pos = m.end()
    if not any(w):
        raise ConfigError(f"{where}: the stepper drives no carriage")
    return w


def from_klipper(cfg, machine) -> None:
    """Read the [carriage …] and [stepper …] sections."""
    from ..config.klipper import _klipper_steps_per_mm, _klipper_travel_limits

    carriages: dict[str, int] = {}
    for section in cfg.sections:
        if section.startswith("carriage "):
            name = section.split(None, 1)[1].strip()
            v = cfg.raw(section, "axis")
            axis = (v.text.strip().lower() if v is not None else name[-1:].lower())
            if axis not in ("x", "y", "z"):
                raise ConfigError(f"[{section}] axis: must be x, y or z", cfg.main)
            carriages[name] = "xyz".index(axis)
            ax = machine.axes[axis]
            ax.home = cfg.get_float(section, "position_endstop", 0.0)
            _klipper_travel_limits(cfg, section, ax)
    if not carriages:
        raise ConfigError("generic_cartesian: no [carriage …] section", cfg.main)
    motors, spm = {}, {}
    for section in cfg.sections:
        if section.startswith("stepper "):
            name = section.split(None, 1)[1].strip()
            v = cfg.raw(section, "carriages")
            if v is None:
                raise ConfigError(f"[{section}] carriages is required", cfg.main)
            motors[name] = parse_carriages(v.text, carriages, f"[{section}] carriages")
            spm[name] = _klipper_steps_per_mm(cfg, section)
    if not motors:
        raise ConfigError("generic_cartesian: no [stepper …] section", cfg.main)
    machine.kinematics_params["motors"] = motors
    machine.kinematics_params["steps_per_mm"] = spm
    for a in "xyz":
        if not any(m[("xyz").index(a)] for m in motors.values()):
            machine.axes[a].position_min, machine.axes[a].position_max = -math.inf, math.inf


PLUGIN = GenericCartesian({"x": (1.0, 0.0, 0.0)}, from_klipper=from_klipper)
PLUGIN._builtin_of = NAME
register(NAME, PLUGIN)
rails = PLUGIN.rails
