"""Cartesian kinematics: one stepper per axis (x, y, z) plus the extruder, a :class:`~.linear.Linear` instance."""
from __future__ import annotations

from .rail import Rail
from .linear import builtin

NAME = "cartesian"


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    """x, y, z, e (or stepper_x … extruder), each with its own axis's steps/mm."""
    return builtin(NAME, klipper_names).rails(machine)
