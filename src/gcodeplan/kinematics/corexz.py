"""CoreXZ kinematics (Klipper's corexz.py, kin_corexz.c): stepper_x = X + Z, stepper_y = Y, stepper_z = X − Z.

A :class:`~.linear.Linear` instance. As in Klipper, ``[stepper_x]`` and
``[stepper_z]`` each take their own section's step distance; without Klipper
names the motors are called a (X + Z), y, b (X − Z) and e.
"""
from __future__ import annotations

from .rail import Rail
from .linear import builtin

NAME = "corexz"


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    """a, y, b, e (or stepper_x, stepper_y, stepper_z, extruder)."""
    return builtin(NAME, klipper_names).rails(machine)
