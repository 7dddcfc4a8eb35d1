"""The step stage as a pipeline sink: planned pieces → exact step times per stepper.

Also marks where the grid must re-anchor: the first segment after a G28 /
SET_KINEMATIC_POSITION row (KIND_WAIT with FLAG_HOMING) re-anchors even when the
position did not jump, as Klipper's set_position does.
"""
from __future__ import annotations

import numpy as np

from ..pipeline import Piece, Sink

from ..schema import FLAG_HOMING, KIND_WAIT


def homing_resets(moves: np.ndarray, segments: np.ndarray, first_move: int,
                  pending: bool = False) -> tuple[np.ndarray, bool]:
    """(uint8 per segment, pending): 1 on the first segment after a homing row.

    ``first_move`` is the global index of ``moves[0]``; SEGMENT.move may be global
    or local to the batch (both are accepted). ``pending`` carries a homing row
    that no segment of the previous batch followed.
    """
    reset = np.zeros(len(segments), np.uint8)
    homing = np.flatnonzero((moves["kind"] == KIND_WAIT) & ((moves["flags"] & FLAG_HOMING) != 0)) \
        if len(moves) else np.zeros(0, np.int64)
    if len(segments) == 0:
        return reset, pending or len(homing) > 0
    if pending:
        reset[0] = 1
    if len(homing) == 0:
        return reset, False
    seg_move = segments["move"].astype(np.int64)
    if seg_move.min() >= first_move and seg_move.max() < first_move + len(moves):
        seg_move = seg_move - first_move
    # segment k re-anchors when a homing row h has prev_move <= h < own move
    prev_move = np.concatenate(([-1], seg_move[:-1]))
    below_own = np.searchsorted(homing, seg_move, side="left")
    below_prev = np.searchsorted(homing, prev_move, side="left")
    reset[below_own > below_prev] = 1
    return reset, bool(homing[-1] >= seg_move[-1])


def segment_batches(source, machine, *, policy: str | None = None, jerk: float | None = None,
                    strict: bool = False, progress=None):
    """(SEGMENT rows, reset flags) per planned piece, streaming (a thin view of :class:`gcodeplan.pipeline.Run`
    for callers that pull batches, e.g. benchmarks feeding the step kernel themselves)."""
    from ..pipeline import Run

    pending = False
    for piece in Run(source, machine, policy=policy, jerk=jerk, strict=strict, progress=progress):
        segs = piece.segments
        reset, pending = homing_resets(piece.moves, segs, piece.first_move, pending)
        yield segs, reset


def rails_from(machine, kinematics=None, klipper_names: bool | None = None):
    """The steppers to generate: the machine's kinematics, or ``kinematics`` (an object with
    ``rails(machine)``, e.g. :class:`gcodeplan.kinematics.Linear`). Klipper's stepper names
    (``stepper_x`` … ``extruder``) when ``klipper_names`` (None: when the machine speaks Klipper's flavor)."""
    from ..kinematics import rails_for

    if kinematics is not None:
        return list(kinematics.rails(machine))
    if klipper_names is None:
        klipper_names = machine.flavor == "klipper"
    return rails_for(machine, klipper_names=klipper_names)


# the steppers a firmware model issues pulses for, by index, as weights over (x, y, z, e): a cartesian build's
# X, Y, Z, E; Marlin's COREXY build steps motor A = X + Y in X's place and B = X − Y in Y's, COREXZ A = X + Z in
# X's and C = X − Z in Z's (Klipper's corexy / corexz rails have these weights)
FIRMWARE_MOTORS = {
    "cartesian": ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
    "corexy": ((1.0, 1.0, 0.0, 0.0), (1.0, -1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
    "corexz": ((1.0, 0.0, 1.0, 0.0), (0.0, 1.0, 0.0, 0.0), (1.0, 0.0, -1.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
}


def firmware_axis(rail, kinematics: str = "cartesian") -> int:
    """The stepper (0..3) of a firmware model whose pulses this rail takes, on a machine of ``kinematics``: the
    one whose weights over (x, y, z, e) are the rail's (FIRMWARE_MOTORS: a cartesian machine's X … E; Marlin's
    Core motors in the place of X, Y or Z); −1 for none."""
    w = rail.weights
    if w is None:
        return -1
    w = tuple(float(v) for v in w) + (0.0,) * (4 - len(w))
    motors = FIRMWARE_MOTORS.get(kinematics, FIRMWARE_MOTORS["cartesian"])
    return motors.index(w) if w in motors else -1


class StepSink(Sink):
    """A pipeline sink that steps every piece: ``sink_fn(stepper_index, times_s, dirs)`` receives the
    steps in order, per stepper, in bounded buffers (see :class:`gcodeplan.stepper.generate.StepGenerator`).
    The grid re-anchors after G28 / SET_KINEMATIC_POSITION (:func:`homing_resets`)."""

    interpretable = False   # its kernels run once per step: never worth interpreting (gcodeplan/_jit.py)

    def __init__(self, rails, sink_fn, *, sds_filter_t: float | None = None, machine=None, ik_search: str = "klipper"):
        """``machine``: its input shaper / pressure advance apply (``machine.limits_row()``); mid-file
        SET_INPUT_SHAPER / SET_PRESSURE_ADVANCE / M900 / M572 come with each piece's LIMITS table. ``ik_search``:
        "klipper" or "exact", how plug-in kinematics' motors are stepped (StepGenerator.IK_SEARCHES)."""
        from .generate import StepGenerator

        self.rails = list(rails)
        settings = machine.limits_row() if machine is not None else None
        self.generator = StepGenerator(self.rails, sink_fn, sds_filter_t=sds_filter_t, settings=settings,
                                       ik_search=ik_search)
        # which stepper of a firmware model's pulses each rail takes (firmware_axis), on the machine's kinematics
        kinematics = getattr(machine, "kinematics", "cartesian")
        self._fw_axis = [firmware_axis(r, kinematics) for r in self.rails]
        self._pending = False

    wants_firmware_steps = True   # a firmware model's own pulses (grbl's, Marlin's interrupt) replace stepping

    def add(self, piece: Piece) -> None:
        fw = getattr(piece, "firmware_steps", None)
        if fw is not None:
            for si, (rail, axis) in enumerate(zip(self.rails, self._fw_axis)):
                if axis < 0:
                    from ..errors import ConfigError

                    raise ConfigError(f"stepper {rail.name!r}: the firmware model issues the pulses of the X, Y, "
                                      "Z and E steppers of a cartesian machine (Marlin: or the motors of a "
                                      "CoreXY / CoreXZ one), and this one follows none of them")
                if axis in fw and len(fw[axis][0]):
                    self.generator.feed_pulses(si, *fw[axis])
            return
        reset, self._pending = homing_resets(piece.moves, piece.segments, piece.first_move, self._pending)
        self.generator.feed(piece.segments, reset, moves=piece.moves, limits=piece.limits,
                            first_move=piece.first_move)

    def close(self, result) -> None:
        self.generator.finish()

    @property
    def stats(self):
        """Per stepper, the running step statistics (:func:`gcodeplan.stepper.kernel.step_stats`)."""
        return self.generator.stats
