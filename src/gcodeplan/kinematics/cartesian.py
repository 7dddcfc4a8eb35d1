"""Cartesian kinematics: one stepper per axis (x, y, z) plus the extruder."""
from __future__ import annotations

from . import Rail, axis_steps_per_mm

NAME = "cartesian"


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    names = ("stepper_x", "stepper_y", "stepper_z", "extruder") if klipper_names else ("x", "y", "z", "e")
    weights = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    return [Rail(n, axis_steps_per_mm(machine, ax), w) for n, ax, w in zip(names, "xyze", weights)]
