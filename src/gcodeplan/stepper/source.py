"""G-code file → SEGMENT batches, through the streaming parser and planner.

Also marks where the grid must re-anchor: the first segment after a G28 /
SET_KINEMATIC_POSITION row (KIND_WAIT with FLAG_HOMING) re-anchors even when the
position did not jump, as Klipper's set_position does.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

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


def segment_batches(path: str, machine, *, policy: str | None = None, jerk: float | None = None,
                    strict: bool = False,
                    progress: Callable[[int], None] | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(SEGMENT rows, reset flags) per planner emission, with bounded memory.

    ``progress(bytes_read)`` is called after each parser batch when the reader reports it.
    """
    from ..gcode import GcodeReader
    from ..planner import StreamPlanner

    policy = policy or machine.junction_policy
    reader = GcodeReader(path, machine, strict=strict)
    planner = StreamPlanner(machine, policy=policy, jerk=jerk)
    first_move = 0
    pending = False

    def emit(pairs):
        nonlocal first_move, pending
        for moves, plan in pairs:
            # blends and S-curves: the planner's own pieces (to_segments only rebuilds trapezoids)
            segs = planner.segments_for(moves, plan, first_move)
            reset, pending = homing_resets(moves, segs, first_move, pending)
            yield segs, reset
            first_move += len(moves)

    for moves in reader.batches():
        yield from emit(planner.feed(moves, reader.limits))
        if progress is not None:
            done = getattr(reader, "bytes_read", None)
            if done is not None:
                progress(done)
    yield from emit(planner.finish())
