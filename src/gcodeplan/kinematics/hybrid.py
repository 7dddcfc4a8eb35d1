"""Hybrid CoreXY and CoreXZ (Klipper's kinematics/hybrid_corexy.py, hybrid_corexz.py) as plug-ins.

Linear machines (stepped by the exact polynomial kernel through their weights): hybrid_corexy has
``stepper_x`` = x − y, ``stepper_y`` = y, ``stepper_z`` = z; hybrid_corexz ``stepper_x`` = x − z,
``stepper_y`` = y, ``stepper_z`` = z. Each motor takes the step distance of its own section. Limits are
cartesian's: per-axis ranges (the machine's axes) and the Z-ratio rule; no hook of their own. Klipper's
dual-carriage variants are not modelled.
"""
from __future__ import annotations

from .plugin import Plugin, register

NAMES = ("hybrid_corexy", "hybrid_corexz")
WEIGHTS = {
    "hybrid_corexy": {"x": (1.0, -1.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)},
    "hybrid_corexz": {"x": (1.0, 0.0, -1.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)},
}
PLUGINS = {}
for _name in NAMES:
    _p = Plugin(WEIGHTS[_name], klipper_names={a: f"stepper_{a}" for a in "xyz"}, extruder="extruder")
    _p._builtin_of = _name
    PLUGINS[_name] = register(_name, _p)
NAME = NAMES[0]


def rails(machine, klipper_names: bool = False):
    """The motors of the machine's hybrid kinematics."""
    return PLUGINS[machine.kinematics].rails(machine, klipper_names)
