"""CoreXY kinematics: motors A = X + Y and B = X − Y, Z and E direct.

Klipper's convention: ``[stepper_x]`` drives A and ``[stepper_y]`` drives B, and
each takes its steps per mm from its own section (A from the x axis, B from y).
"""
from __future__ import annotations

from . import Rail, axis_steps_per_mm

NAME = "corexy"


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    names = ("stepper_x", "stepper_y", "stepper_z", "extruder") if klipper_names else ("a", "b", "z", "e")
    weights = ((1.0, 1.0, 0.0, 0.0), (1.0, -1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    return [Rail(n, axis_steps_per_mm(machine, ax), w) for n, ax, w in zip(names, "xyze", weights)]
