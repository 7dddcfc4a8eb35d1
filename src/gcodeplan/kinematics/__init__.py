"""Kinematics: from toolhead axes (x, y, z, e) to stepper positions.

Each kinematics is one module in this package exposing ``NAME`` and
``rails(machine, klipper_names) -> list[Rail]``; a user's own kinematics is any
object with a ``rails(machine, klipper_names)`` method, e.g. a
:class:`~.linear.Linear` (``gcodeplan.kinematics.Linear``), passed where the
step entry points take ``kinematics=``. A *rail* is one stepper: its
name, its steps per mm and how its position follows from the toolhead axes.

Cartesian and corexy are *linear*: a stepper position is a fixed weighted sum of
the axes, ``s = w_x·x + w_y·y + w_z·z + w_e·e``. A linear sum of cubic pieces is
again a cubic piece, so :func:`stepper_pieces` turns the planner's SEGMENT rows
into the stepper's own polynomial pieces exactly and the step kernel never sees
the kinematics. Delta (:mod:`.delta`, ``s = z + √(L² − (x−x_t)² − (y−y_t)²)``) is not linear: its
rails have ``weights = None`` and carry their ``tower``; the step generator runs
the delta kernel on the x, y, z pieces; the step convention and the output
layout stay the same.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

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
    stepped by the generic engine with ``ik_params`` (:mod:`.plugin`); ``period``: the period of a cyclic
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
_LEGACY = ("cartesian", "corexy", "corexz", "delta")


def kinematics_module(name: str):
    """The module implementing kinematics ``name`` (ConfigError when unknown)."""
    mod = KINEMATICS_MODULES.get(name)
    if mod is None:
        from .plugin import names

        raise ConfigError(f"kinematics: unknown value {name!r} "
                          f"(known: {', '.join(sorted(names()))})")
    return importlib.import_module(f"{__name__}.{mod}")


def rails_for(machine, klipper_names: bool = False, kinematics=None) -> list[Rail]:
    """The machine's steppers, in output order. Klipper section names when ``klipper_names``.

    ``kinematics``: None (the machine's own), a built-in name, or an object with
    ``rails(machine, klipper_names)`` (e.g. :class:`~.linear.Linear`).
    """
    if kinematics is None:
        kinematics = machine.kinematics
    if isinstance(kinematics, str):
        from .plugin import registered

        plugin = registered(kinematics) if kinematics not in _LEGACY else None
        if plugin is not None:
            rails = list(plugin.rails(machine, klipper_names))
        else:
            rails = kinematics_module(kinematics).rails(machine, klipper_names)
    elif callable(getattr(kinematics, "rails", None)):
        rails = list(kinematics.rails(machine, klipper_names))
    else:
        raise ConfigError(f"kinematics: expected a name or an object with rails(machine, klipper_names), "
                          f"got {type(kinematics).__name__}")
    for r in rails:
        if not (r.steps_per_mm > 0 and np.isfinite(r.steps_per_mm)):
            raise ConfigError(f"{r.name}: steps_per_mm must be a positive number, got {r.steps_per_mm!r}")
    return rails


def axis_steps_per_mm(machine, axis: str) -> float:
    """The machine's steps/mm of axis ``axis`` (x, y, z, e)."""
    return float(machine.axes[axis].steps_per_mm)


def stepper_pieces(segments: np.ndarray, rail: Rail) -> tuple[np.ndarray, ...]:
    """(t0, dt, p, v, a, j) of the rail's position for every SEGMENT row.

    s(τ) = p + v·τ + a·τ²/2 + j·τ³/6 with τ = t − t0 (the SEGMENT convention).
    Zero weights are skipped and unit weights copy, so a cartesian stepper gets
    the planner's coefficients bit for bit.
    """
    if rail.weights is None:
        raise NotImplementedError(f"{rail.name}: non-linear kinematics need their own kernel")
    t0 = np.ascontiguousarray(segments["t0"], dtype=np.float64)
    dt = np.ascontiguousarray(segments["dt"], dtype=np.float64)
    out = []
    for prefix in ("p", "v", "a", "j"):
        acc = None
        for w, ax in zip(rail.weights, AXIS_FIELDS):
            if w == 0.0:
                continue
            col = segments[prefix + ax]
            term = col if w == 1.0 else (-col if w == -1.0 else w * col)
            acc = np.array(term, dtype=np.float64) if acc is None else acc + term
        if acc is None:
            acc = np.zeros(len(segments), dtype=np.float64)
        out.append(np.ascontiguousarray(acc))
    return (t0, dt, *out)


from .linear import Linear  # noqa: E402  (public: gcodeplan.kinematics.Linear; needs Rail above)
from .plugin import Plugin, names, register, registered, unregister  # noqa: E402  (needs Rail above)

__all__ = ["Rail", "Linear", "Plugin", "register", "unregister", "registered", "names", "rails_for",
           "stepper_pieces", "kinematics_module", "KINEMATICS_MODULES"]
