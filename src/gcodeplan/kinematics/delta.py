"""Linear delta kinematics (Klipper's kinematics/delta.py and chelper/kin_delta.c).

Three vertical towers a, b, c stand on a circle of radius ``delta_radius`` at angles 210°, 330°, 90°
(by default): tower i at (t_x, t_y) = radius·(cos θ_i, sin θ_i). A carriage slides on each tower; an arm
of length L joins it to the effector, so for a nozzle at (x, y, z) the carriage height is

    c_i = z + √(L_i² − (x − t_x)² − (y − t_y)²)                          (docs/design.md, "Delta")

Carriage motion is not a linear sum of the axes, so the rails carry their tower (``Rail.tower``) and the
step kernel (:func:`gcodeplan.stepper.kernel.gen_steps_delta`) solves this formula itself.

What Klipper derives from the config, all in :class:`DeltaGeometry` with Klipper's arithmetic (so the
floats are Klipper's): the absolute endstop heights ``position_endstop_i + √(L_i² − radius²)``, ``max_z``
= the lowest position_endstop, ``limit_z`` = min(abs_endstop_i − L_i) above which the reachable radius
tapers, and three radii from ``ratio_to_xy(q) = q·√(L_min²/(q² + 1) − h²) + h − radius`` (h = half the
smallest step distance), the XY distance at which a tower moves q times faster than the effector:
slow zone beyond ratio_to_xy(3), very slow beyond ratio_to_xy(6), unreachable beyond
min(print_radius, L_min − radius, ratio_to_xy(12)).

The planner's slow-zone rule reads its numbers from the LIMITS columns ``delta_*``
(:meth:`gcodeplan.machine.Machine.limits_row`); the reader refuses unreachable moves with
:func:`reach_check` (registered with :func:`gcodeplan.gcode.bounds.register_reach_check`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .rail import Rail

NAME = "delta"
TOWERS = ("a", "b", "c")
DEFAULT_ANGLES = (210.0, 330.0, 90.0)   # degrees, Klipper's defaults for stepper_a/b/c
SLOW_RATIO = 3.0                        # Klipper: moves slow down where a tower runs 3× the effector speed
KLIPPER_MIN_MOVE_D = 1e-9               # mm: Klipper checks only moves with XYZ motion (is_kinematic_move)


@dataclass(frozen=True)
class DeltaGeometry:
    """Klipper's derived delta numbers (mm, mm²); see the module docstring for the formulas."""

    radius: float
    arm_lengths: tuple[float, float, float]
    arm2: tuple[float, float, float]
    towers_xy: tuple[tuple[float, float], ...]
    abs_endstops: tuple[float, float, float]
    max_z: float
    min_z: float
    limit_z: float
    min_arm_length: float
    slow_xy2: float
    very_slow_xy2: float
    max_xy2: float
    home_position: tuple[float, float, float]

    @staticmethod
    def from_machine(machine) -> "DeltaGeometry":
        """The geometry of a delta machine (ConfigError when its delta settings are missing or impossible)."""
        check_machine(machine)
        radius = float(machine.delta_radius)
        print_radius = radius if machine.print_radius is None else float(machine.print_radius)
        arms = tuple(float(a) for a in machine.delta_arm_length)
        endstops = tuple(float(e) for e in machine.delta_position_endstop)
        arm2 = tuple(a ** 2 for a in arms)
        # same operations, same order as Klipper's delta.py, so the floats agree bit for bit
        abs_endstops = tuple(e + math.sqrt(a2 - radius ** 2) for e, a2 in zip(endstops, arm2))
        towers = tuple((math.cos(math.radians(ang)) * radius, math.sin(math.radians(ang)) * radius)
                       for ang in machine.delta_angle)
        max_z = min(endstops)
        limit_z = min(ep - arm for ep, arm in zip(abs_endstops, arms))
        half_min_step_dist = min(1.0 / float(s) for s in machine.delta_steps_per_mm) * 0.5
        min_arm = min(arms)

        def ratio_to_xy(ratio: float) -> float:
            return (ratio * math.sqrt(min_arm ** 2 / (ratio ** 2 + 1.0) - half_min_step_dist ** 2)
                    + half_min_step_dist - radius)

        max_xy2 = min(print_radius, min_arm - radius, ratio_to_xy(4.0 * SLOW_RATIO)) ** 2
        home = trilaterate(towers, abs_endstops, arm2)
        return DeltaGeometry(radius, arms, arm2, towers, abs_endstops, max_z, float(machine.minimum_z_position),
                             limit_z, min_arm, ratio_to_xy(SLOW_RATIO) ** 2, ratio_to_xy(2.0 * SLOW_RATIO) ** 2,
                             max_xy2, home)

    def carriage_heights(self, x, y, z) -> np.ndarray:
        """Carriage heights (mm) of towers a, b, c for nozzle positions x, y, z (mm; arrays broadcast):
        shape (3, …). NaN where an arm cannot reach."""
        x, y, z = np.asarray(x, float), np.asarray(y, float), np.asarray(z, float)
        out = []
        for a2, (tx, ty) in zip(self.arm2, self.towers_xy):
            dx = tx - x
            dy = ty - y
            with np.errstate(invalid="ignore"):
                out.append(np.sqrt(a2 - dx * dx - dy * dy) + z)
        return np.stack(out)

    def reach_limit_xy2(self, z) -> np.ndarray:
        """mm²: the largest x² + y² a move may end at, at height z (mm). Above limit_z an arm would
        have to tilt past horizontal further out, so the radius tapers (Klipper's check_move)."""
        z = np.asarray(z, float)
        lim = np.full(z.shape, self.max_xy2)
        above = z > self.limit_z
        if np.any(above):
            with np.errstate(invalid="ignore"):
                allowed = self.radius - np.sqrt(self.min_arm_length ** 2
                                                - (self.min_arm_length - (z[above] - self.limit_z)) ** 2)
            lim[above] = np.minimum(lim[above], allowed ** 2)
        return lim


def trilaterate(centres, heights, arm2) -> tuple[float, float, float]:
    """The effector point at distance √arm2_i from the carriage points (t_x, t_y, height_i), the one
    below the carriages (mm): the forward kinematics, used for the home position."""
    p = [np.array([cx, cy, h], float) for (cx, cy), h in zip(centres, heights)]
    d21 = p[1] - p[0]
    d = float(np.linalg.norm(d21))
    ex = d21 / d
    d31 = p[2] - p[0]
    i = float(ex @ d31)
    ey = d31 - i * ex
    j = float(np.linalg.norm(ey))
    ey = ey / j
    ez = np.cross(ex, ey)
    x = (arm2[0] - arm2[1] + d * d) / (2.0 * d)
    y = (arm2[0] - arm2[2] + i * i + j * j) / (2.0 * j) - i * x / j
    z2 = arm2[0] - x * x - y * y
    if not z2 >= 0.0:
        raise ConfigError("delta: the arms cannot reach a common point with the carriages at their endstops "
                          "(check delta_radius, arm_length, position_endstop)")
    base = p[0] + x * ex + y * ey
    a, b = base + math.sqrt(z2) * ez, base - math.sqrt(z2) * ez
    pt = a if a[2] < b[2] else b
    return float(pt[0]), float(pt[1]), float(pt[2])


def check_machine(machine) -> None:
    """ConfigError unless the delta settings are usable, with Klipper's checks (arm longer than the radius,
    minimum_z_position ≤ max_z)."""
    r = machine.delta_radius
    if not (isinstance(r, (int, float)) and r > 0 and math.isfinite(r)):
        raise ConfigError(f"delta.radius: kinematics 'delta' needs delta_radius > 0 mm, got {r!r}")
    pr = machine.print_radius
    if pr is not None and not (pr > 0 and math.isfinite(pr)):
        raise ConfigError(f"delta.print_radius: must be a positive number, got {pr!r}")
    for key, vals in (("arm_length", machine.delta_arm_length), ("angle", machine.delta_angle),
                      ("position_endstop", machine.delta_position_endstop),
                      ("steps_per_mm", machine.delta_steps_per_mm)):
        if len(vals) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            raise ConfigError(f"delta.{key}: three finite numbers (towers a, b, c), got {vals!r}")
    for t, arm in zip(TOWERS, machine.delta_arm_length):
        if not arm > r:
            raise ConfigError(f"delta.arm_length: tower {t}'s arm ({arm:g} mm) must be longer than delta_radius "
                              f"({r:g} mm)")
    for t, s in zip(TOWERS, machine.delta_steps_per_mm):
        if not s > 0:
            raise ConfigError(f"delta.steps_per_mm: tower {t} must have steps_per_mm > 0, got {s!r}")
    zmin = machine.minimum_z_position
    if not math.isfinite(zmin) or zmin > min(machine.delta_position_endstop):
        raise ConfigError(f"delta.minimum_z_position: must be at most the lowest position_endstop "
                          f"({min(machine.delta_position_endstop):g}), got {zmin!r}")


def rails(machine, klipper_names: bool = False) -> list[Rail]:
    """Towers a, b, c (``stepper_a`` … with Klipper names) and the extruder; carriage height in mm."""
    g = DeltaGeometry.from_machine(machine)
    out = []
    for t, spm, a2, (tx, ty) in zip(TOWERS, machine.delta_steps_per_mm, g.arm2, g.towers_xy):
        out.append(Rail(f"stepper_{t}" if klipper_names else t, float(spm), None, tower=(a2, tx, ty)))
    out.append(Rail("extruder" if klipper_names else "e", float(machine.axes["e"].steps_per_mm),
                    (0.0, 0.0, 0.0, 1.0)))
    return out


def reach_check(batch: np.ndarray, machine) -> tuple[int, str] | None:
    """(row, message) of the first move of a MOVE batch a delta cannot reach, or None.

    Klipper's DeltaKinematics.check_move, per move with XYZ motion: the end point must lie within the
    reachable radius at its height (:meth:`DeltaGeometry.reach_limit_xy2`) and between minimum_z_position
    and max_z, except a move to the home XY position below the home height (homing). Klipper's text.
    """
    from ..schema import KIND_PRINT, KIND_TRAVEL

    if batch.size == 0:
        return None
    g = _geometry(machine)
    kind = batch["kind"]
    x1, y1, z1 = batch["x1"], batch["y1"], batch["z1"]
    dx, dy, dz = x1 - batch["x0"], y1 - batch["y0"], z1 - batch["z0"]
    moving = ((kind == KIND_TRAVEL) | (kind == KIND_PRINT)) & (np.sqrt(dx * dx + dy * dy + dz * dz)
                                                                 >= KLIPPER_MIN_MOVE_D)
    if not np.any(moving):
        return None
    end_xy2 = x1 * x1 + y1 * y1
    bad = moving & ((end_xy2 > g.reach_limit_xy2(z1)) | (z1 > g.max_z) | (z1 < g.min_z))
    homing = (x1 == g.home_position[0]) & (y1 == g.home_position[1]) & (z1 >= g.min_z) & (z1 <= g.home_position[2])
    bad &= ~homing
    if not np.any(bad):
        return None
    i = int(np.argmax(bad))
    mv = batch[i]
    r = math.sqrt(float(end_xy2[i]))
    reach = math.sqrt(float(g.reach_limit_xy2(np.array([mv["z1"]]))[0]))
    why = (f"Z {mv['z1']:.3f} is outside minimum_z_position {g.min_z:g} … max_z {g.max_z:g}"
           if not g.min_z <= mv["z1"] <= g.max_z else
           f"radius {r:.3f} mm is beyond the delta's reach of {reach:.3f} mm at this height")
    return i, (f"Move out of range: {mv['x1']:.3f} {mv['y1']:.3f} {mv['z1']:.3f} [{mv['e1']:.3f}] "
               f"({why}: Klipper refuses this move)")


_CACHE: dict[tuple, DeltaGeometry] = {}


def _geometry(machine) -> DeltaGeometry:
    """:meth:`DeltaGeometry.from_machine`, cached per distinct set of delta settings (one per batch otherwise)."""
    key = (machine.delta_radius, machine.print_radius, machine.minimum_z_position, tuple(machine.delta_arm_length),
           tuple(machine.delta_angle), tuple(machine.delta_position_endstop), tuple(machine.delta_steps_per_mm))
    g = _CACHE.get(key)
    if g is None:
        g = _CACHE[key] = DeltaGeometry.from_machine(machine)
    return g


def _register() -> None:
    from ..gcode.bounds import register_reach_check

    register_reach_check(NAME, reach_check)


_register()
