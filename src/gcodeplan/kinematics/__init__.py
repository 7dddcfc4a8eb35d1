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

Every other kinematics is a plug-in (:mod:`.plugin`, ``gcodeplan.kinematics.register``): motors given by a
compiled inverse-kinematics function ``ik(x, y, z, params)`` (rails with ``ik`` set, stepped by Klipper's
search :func:`gcodeplan.stepper.kernel.itersolve_steps` with ``ik`` as its position callback) or by linear weights, plus an optional limits
hook the planner applies to every move. Klipper's polar, rotary_delta, winch, deltesian, hybrid_corexy,
hybrid_corexz and generic_cartesian are built in that way. :mod:`.rail` holds :class:`Rail` and the table of
built-in modules (imported by the modules without importing this package: no import cycle).
"""
from __future__ import annotations

import importlib

import numpy as np

from ..errors import ConfigError
from .rail import AXIS_FIELDS, KINEMATICS_MODULES, LEGACY as _LEGACY, Rail


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


from .linear import Linear  # noqa: E402  (public: gcodeplan.kinematics.Linear)
from .plugin import Plugin, names, register, registered, unregister  # noqa: E402

__all__ = ["Rail", "AXIS_FIELDS", "Linear", "Plugin", "register", "unregister", "registered", "names", "rails_for",
           "stepper_pieces", "kinematics_module", "KINEMATICS_MODULES"]
