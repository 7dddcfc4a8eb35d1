"""The data every kinematics module shares: :class:`Rail` (one stepper) and the built-in kinematics' modules.

Kept apart from the package's ``__init__`` so that the modules implementing kinematics import it without
importing the package that imports them (no import cycle).
"""
from __future__ import annotations

from dataclasses import dataclass

# name -> module inside this package
KINEMATICS_MODULES = {
    "cartesian": "cartesian",
    "corexy": "corexy",
    "corexz": "corexz",
    "delta": "delta",
    # Klipper's other kinematics, each a plug-in (:mod:`.plugin`) through the one step engine
    "polar": "polar",
    "rotary_delta": "rotary_delta",
    "winch": "winch",
    "deltesian": "deltesian",
    "hybrid_corexy": "hybrid",
    "hybrid_corexz": "hybrid",
    "generic_cartesian": "generic_cartesian",
}

AXIS_FIELDS = ("x", "y", "z", "e")


@dataclass(frozen=True)
class Rail:
    """One stepper motor.

    ``weights``: stepper position (mm of the stepper's own travel) as
    Σ weights[i]·axis[i] over (x, y, z, e); ``None`` for non-linear kinematics.
    ``tower``: a delta tower's (arm length² mm², tower x mm, tower y mm): the position is the carriage
    height z + √(arm² − (x − tower x)² − (y − tower y)²) (:mod:`.delta`); None otherwise.
    ``ik``: a plug-in's compiled inverse kinematics ``ik(x, y, z, params)`` → motor position (mm or rad),
    stepped by Klipper's search (stepper.kernel.itersolve_steps) with ``ik_params`` (:mod:`.plugin`); ``period``: the period of a cyclic
    motor position (2π for a turntable), 0 for none. ``steps_per_mm`` is then steps per unit of that position.
    """

    name: str
    steps_per_mm: float
    weights: tuple[float, float, float, float] | None
    tower: tuple[float, float, float] | None = None
    ik: object = None
    ik_params: tuple = ()
    period: float = 0.0

    @property
    def step_dist(self) -> float:
        """mm of stepper travel per step (Klipper's ``step_dist``)."""
        return 1.0 / self.steps_per_mm


# the kinematics stepped by their own modules (linear weights, the delta kernel); every other name is a plug-in
LEGACY = ("cartesian", "corexy", "corexz", "delta")
