"""Cable winch kinematics (Klipper's kinematics/winch.py, chelper/kin_winch.c) as a plug-in.

Each motor ``stepper_a``, ``stepper_b``, … winds a cable to an anchor (anchor_x, anchor_y, anchor_z); its
position is the cable length |anchor − (x, y, z)| in mm. Klipper's winch has no limits at all: its check_move
does nothing (no bounds, no Z limits, max_z_velocity / max_z_accel not read), so the plug-in has no hook and
the Z axis no limits of its own.

``machine.kinematics_params``: ``anchors`` (a list of [x, y, z] mm, one per motor, at least 3, at most 26) and
``steps_per_mm`` (one per motor).
"""
from __future__ import annotations

import math
import string

import numpy as np

from .._jit import njit
from ..errors import ConfigError
from .plugin import Plugin, register

NAME = "winch"


@njit(cache=True)
def cable_length(x, y, z, params):
    """mm: the distance from the anchor (params[0:3]) to the toolhead."""
    dx = params[0] - x
    dy = params[1] - y
    dz = params[2] - z
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def _anchors(machine) -> list[tuple[float, float, float]]:
    anchors = machine.kinematics_params.get("anchors")
    try:
        out = [tuple(float(v) for v in a) for a in anchors]
    except (TypeError, ValueError):
        out = []
    if not 3 <= len(out) <= 26 or any(len(a) != 3 or not all(map(math.isfinite, a)) for a in out):
        raise ConfigError(f"kinematics_params.anchors: 3 to 26 anchors [x, y, z] (mm) for kinematics 'winch', "
                          f"got {anchors!r}")
    return out


class WinchPlugin(Plugin):
    """The winch: as many motors as anchors."""

    def rails(self, machine, klipper_names: bool = False):
        anchors = _anchors(machine)
        spm = machine.kinematics_params.get("steps_per_mm")
        if not isinstance(spm, (list, tuple)) or len(spm) != len(anchors):
            raise ConfigError("kinematics_params.steps_per_mm: one number per winch anchor")
        names = [string.ascii_lowercase[i] for i in range(len(anchors))]
        inner = Plugin({n: cable_length for n in names}, {n: float(s) for n, s in zip(names, spm)},
                       motor_params={n: np.array(a) for n, a in zip(names, anchors)},
                       klipper_names={n: f"stepper_{n}" for n in names})
        inner.name = NAME
        return inner.rails(machine, klipper_names)


def from_klipper(cfg, machine) -> None:
    """Read [stepper_a] … (anchor_x/y/z and the step distance): a, b, c required, then as long as they exist."""
    from ..config.klipper import _klipper_steps_per_mm

    anchors, spm = [], []
    for i, t in enumerate(string.ascii_lowercase):
        section = f"stepper_{t}"
        if i >= 3 and not cfg.has(section):
            break
        if not cfg.has(section):
            raise ConfigError(f"[{section}] section is required (kinematics: winch)", cfg.main)
        anchors.append([cfg.get_float(section, f"anchor_{a}", required=True) for a in "xyz"])
        spm.append(_klipper_steps_per_mm(cfg, section))
    machine.kinematics_params["anchors"] = anchors
    machine.kinematics_params["steps_per_mm"] = spm
    for a in "xyz":
        ax = machine.axes[a]
        ax.position_min, ax.position_max = -math.inf, math.inf
        if a == "z":
            ax.max_velocity = ax.max_accel = math.inf


PLUGIN = WinchPlugin({"a": cable_length}, {"a": 1.0}, from_klipper=from_klipper)
PLUGIN._builtin_of = NAME
register(NAME, PLUGIN)
rails = PLUGIN.rails
