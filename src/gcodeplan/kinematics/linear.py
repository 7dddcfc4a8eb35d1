"""Linear kinematics: every motor a fixed linear combination of the toolhead axes.

``s_motor = w_x·x + w_y·y + w_z·z (+ w_e·e)`` in mm of the motor's own travel.
Cartesian (one motor per axis), corexy (A = X + Y, B = X − Y), corexz
(Klipper's corexz.py: stepper_x = X + Z, stepper_z = X − Z), hybrid gantries and
a skewed frame are all instances; the built-ins of this package are defined
with this class (see :data:`BUILTIN_WEIGHTS`).

The extruder: a mapping whose weights are 3-tuples (X, Y, Z) gets an automatic
extruder rail (E weight 1) appended under the name ``extruder`` (``extruder=``
picks another name, ``extruder=None`` leaves it out). A mapping that gives
4-tuples (X, Y, Z, E) with an E weight on any motor gets no automatic rail: the
user's own rails drive the filament.

Steps per mm: ``steps_per_mm`` maps a motor name to steps/mm; a motor it does
not name takes the machine's ``[axis.<a>] steps_per_mm`` of the axis
``steps_from[name]`` names, by default its first axis with a non-zero weight,
and the automatic extruder the machine's E. Klipper's convention is that a motor
takes the step distance of its own section although it drives a combination
(corexy's stepper_y, B = X − Y, takes [stepper_y]'s): the built-ins say so through
``steps_from``.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

from ..errors import ConfigError
from .rail import AXIS_FIELDS, Rail

# built-in linear kinematics: (machine-file names, Klipper section names, weights over x, y, z, e)
BUILTIN_WEIGHTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], tuple[tuple[float, ...], ...]]] = {
    "cartesian": (("x", "y", "z"), ("stepper_x", "stepper_y", "stepper_z"),
                  ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))),
    "corexy": (("a", "b", "z"), ("stepper_x", "stepper_y", "stepper_z"),
               ((1.0, 1.0, 0.0), (1.0, -1.0, 0.0), (0.0, 0.0, 1.0))),
    # Klipper's corexz.py / kin_corexz.c: stepper_x = x + z, stepper_y = y, stepper_z = x − z
    "corexz": (("a", "y", "b"), ("stepper_x", "stepper_y", "stepper_z"),
               ((1.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, -1.0))),
}


class Linear:
    """A linear machine: ``Linear({"stepper_a": (1, 1, 0), ...}, steps_per_mm={"stepper_a": 80, ...})``.

    ``mapping``: motor name → weights over (x, y, z) or (x, y, z, e), unitless (mm
    of motor travel per mm of axis travel). ``steps_per_mm``: motor name → steps/mm
    (optional per motor, see the module doc). ``extruder``: name of the automatic
    extruder rail, or None for none. ``steps_from``: motor name → axis letter
    (x, y, z, e) whose machine steps/mm a motor without its own takes. Motors come out in the mapping's order, the
    automatic extruder last.
    """

    name = "linear"

    def __init__(self, mapping: Mapping[str, tuple[float, ...]], steps_per_mm: Mapping[str, float] | None = None,
                 *, extruder: str | None = "extruder", steps_from: Mapping[str, str] | None = None):
        if not isinstance(mapping, Mapping) or not mapping:
            raise ConfigError("Linear kinematics: mapping must be a non-empty {motor name: weights} dict")
        weights: dict[str, tuple[float, float, float, float]] = {}
        for name, w in mapping.items():
            if not isinstance(name, str) or not name:
                raise ConfigError(f"Linear kinematics: motor names must be non-empty strings, got {name!r}")
            try:
                vals = tuple(float(x) for x in w)
            except (TypeError, ValueError):
                raise ConfigError(f"Linear kinematics: {name}: weights must be 3 or 4 numbers, got {w!r}") from None
            if len(vals) not in (3, 4) or not all(math.isfinite(x) for x in vals):
                raise ConfigError(f"Linear kinematics: {name}: weights must be 3 or 4 finite numbers "
                                  f"(x, y, z[, e]), got {w!r}")
            if not any(vals):
                raise ConfigError(f"Linear kinematics: {name}: all weights are zero (the motor never moves)")
            weights[name] = vals + (0.0,) * (4 - len(vals))
        spm = dict(steps_per_mm or {})
        unknown = set(spm) - set(weights) - ({extruder} if extruder else set())
        if unknown:
            raise ConfigError(f"Linear kinematics: steps_per_mm names unknown motor(s) {sorted(unknown)}")
        for name, v in spm.items():
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ConfigError(f"Linear kinematics: {name}: steps_per_mm must be a positive number, got {v!r}")
        drives_e = any(w[3] != 0.0 for w in weights.values())
        if extruder is not None and not drives_e:
            if extruder in weights:
                raise ConfigError(f"Linear kinematics: the automatic extruder rail {extruder!r} clashes with a "
                                  f"motor of that name (pass extruder=None or another name)")
            weights[extruder] = (0.0, 0.0, 0.0, 1.0)
        steps_from = dict(steps_from or {})
        for name, ax in steps_from.items():
            if name not in weights or ax not in AXIS_FIELDS:
                raise ConfigError(f"Linear kinematics: steps_from: {name!r} → {ax!r} is not a motor → axis "
                                  f"(x, y, z, e)")
        self.weights = weights
        self.steps_per_mm = {k: float(v) for k, v in spm.items()}
        self.steps_from = steps_from

    def rails(self, machine=None, klipper_names: bool = False) -> list[Rail]:
        """The motors as :class:`Rail` rows (``klipper_names`` is ignored: the names are the mapping's).

        Motors without their own steps/mm take the machine's (ConfigError when there is no machine).
        """
        out = []
        for name, w in self.weights.items():
            spm = self.steps_per_mm.get(name)
            if spm is None:
                if machine is None:
                    raise ConfigError(f"Linear kinematics: {name}: no steps_per_mm given and no machine to take "
                                      f"it from")
                axis = self.steps_from.get(name) or next(ax for ax, x in zip(AXIS_FIELDS, w) if x != 0.0)
                spm = float(machine.axes[axis].steps_per_mm)
            out.append(Rail(name, spm, w))
        return out

    def __repr__(self) -> str:
        return f"Linear({self.weights!r}, steps_per_mm={self.steps_per_mm!r})"


def builtin(kind: str, klipper_names: bool = False) -> Linear:
    """The built-in linear kinematics ``kind`` (cartesian, corexy, corexz) as a :class:`Linear`.

    Motor names are Klipper's sections (stepper_x … extruder) with ``klipper_names``,
    else gcodeplan's short names (x y z e; a b z e; a y b e). Steps/mm come from the machine.
    """
    short, klipper, w = BUILTIN_WEIGHTS[kind]
    names = klipper if klipper_names else short
    # each motor takes its own Klipper section's step distance: the i-th motor the i-th axis
    return Linear(dict(zip(names, w)), extruder="extruder" if klipper_names else "e",
                  steps_from=dict(zip(names, "xyz")))
