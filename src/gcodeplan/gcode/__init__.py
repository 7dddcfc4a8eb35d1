"""gcode stage: G-code text -> MOVE arrays (streaming), with the LIMITS table, layers, features and a summary.

::

    from gcodeplan.gcode import GcodeReader, read_moves, ParseSummary
    r = GcodeReader(path, machine, strict=False, batch_moves=8192)
    for moves in r.batches():   # MOVE_DTYPE arrays in file order
        ...
    r.limits, r.layer_z, r.features, r.summary

Conventions: MOVE ``e0``/``e1`` are a running machine E that ``G92 E`` does not reset (``e1 − e0`` is the
commanded extrusion after M221); E is relative under G91 or M83 (Klipper's rule; on
Marlin the last of G90/G91/M82/M83 decides); coordinates are machine
mm after G20, work offsets, G92 and tool length offsets. The hot path is a numba byte scanner
(:mod:`.scan`); every other line goes through the Python interpreter (:mod:`.interp`).
"""
from .reader import GcodeReader, read_moves
from .summary import ParseSummary

__all__ = ["GcodeReader", "read_moves", "ParseSummary"]
