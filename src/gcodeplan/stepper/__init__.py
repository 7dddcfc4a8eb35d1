"""stepper stage: exact per-stepper step times from the plan's SEGMENT rows.

Modules: :mod:`.kernel` (numba step solver, step+dir+step filter, statistics),
:mod:`.generate` (streaming driver over SEGMENT batches), :mod:`.compress`
(Klipper-style queue_step runs), :mod:`.export` (atomic .npz/.csv writers),
:mod:`.source` (G-code file → SEGMENT batches), :mod:`.synth` (hand-built plans),
:mod:`.steps_cmd` (the ``steps`` command). Kinematics live in
:mod:`gcodeplan.kinematics`.

This module stays free of numba so that ``gcodeplan --help`` is fast.
"""

DEFAULT_CLOCK_HZ = 50_000_000.0      # Klipper's Linux-process MCU clock
DEFAULT_MAX_ERROR_S = 25e-6          # Klipper max_stepcompress_error
KLIPPER_SDS_FILTER_T = 750e-6        # s, Klipper stepcompress SDS_FILTER_TIME
