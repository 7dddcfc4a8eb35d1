"""CoreXY kinematics: motors A = X + Y and B = X − Y, Z and E direct (a :class:`~.linear.Linear` instance).

Klipper's convention: ``[stepper_x]`` drives A and ``[stepper_y]`` drives B, and
each takes its steps per mm from its own section (A from the x axis, B from y).
"""
from __future__ import annotations

from .rail import Rail
from .linear import builtin

NAME = "corexy"


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    """a, b, z, e (or stepper_x … extruder)."""
    return builtin(NAME, klipper_names).rails(machine)
