"""Drive the step kernel over a stream of SEGMENT batches, one buffer per stepper.

:class:`StepGenerator` takes SEGMENT arrays batch by batch (as the streaming
planner emits them), turns them into each stepper's polynomial pieces through
the kinematics, and runs :func:`kernel.gen_steps` into a preallocated buffer per
stepper. A full buffer is handed to ``sink(stepper_index, times, dirs)`` and
reused, so memory stays bounded whatever the file size. The optional
step+dir+step filter and the per-stepper statistics run on the way out.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from ..kinematics import Rail, rails_for, stepper_pieces
from . import KLIPPER_SDS_FILTER_T, kernel  # noqa: F401  (re-exported)

DEFAULT_CHUNK_STEPS = 1 << 20

Sink = Callable[[int, np.ndarray, np.ndarray], None]


class StepGenerator:
    """Exact per-stepper step times for a plan fed in SEGMENT batches.

    ``sds_filter_t``: when set (s), apply Klipper's step+dir+step filter with that
    window before the sink sees the steps. ``stats[i]`` is the running
    :func:`kernel.step_stats` vector of stepper i (after the filter).
    """

    def __init__(self, rails: list[Rail], sink: Sink, *, chunk_steps: int = DEFAULT_CHUNK_STEPS,
                 sds_filter_t: float | None = None):
        self.rails = list(rails)
        self.sink = sink
        self.sds_filter_t = sds_filter_t
        n = len(self.rails)
        self.states = [kernel.new_state() for _ in range(n)]
        self.stats = [kernel.new_stats() for _ in range(n)]
        self._sds = [np.zeros(kernel.SDS_STATE_LEN) for _ in range(n)]
        self._buf_t = [np.empty(chunk_steps, np.float64) for _ in range(n)]
        self._buf_d = [np.empty(chunk_steps, np.int8) for _ in range(n)]
        self._fill = [0] * n
        self.steps_generated = 0      # before the filter

    def feed(self, segments: np.ndarray, reset: np.ndarray | None = None) -> None:
        """Generate the steps of one batch of SEGMENT rows (in time order, following the previous batch).

        ``reset``: optional uint8 per row, non-zero where the position was set
        just before the row (G28 / SET_KINEMATIC_POSITION) so the grid re-anchors.
        """
        if len(segments) == 0:
            return
        if reset is None:
            reset = np.zeros(len(segments), np.uint8)
        else:
            reset = np.ascontiguousarray(reset, dtype=np.uint8)
        for si, rail in enumerate(self.rails):
            t0, dt, p, v, a, j = stepper_pieces(segments, rail)
            self._run(si, t0, dt, p, v, a, j, reset)

    def _run(self, si, t0, dt, p, v, a, j, reset):
        start = 0
        n_pieces = len(t0)
        step_dist = self.rails[si].step_dist
        while start < n_pieces:
            buf_t = self._buf_t[si]
            buf_d = self._buf_d[si]
            nxt, fill, need = kernel.gen_steps(t0, dt, p, v, a, j, reset, step_dist, self.states[si],
                                               start, buf_t, buf_d, self._fill[si])
            if need < 0:
                raise RuntimeError(f"{self.rails[si].name}: plan piece at t = {t0[nxt]!r} s has a non-finite "
                                   f"coefficient (a planner bug)")
            self.steps_generated += fill - self._fill[si]
            self._fill[si] = fill
            start = nxt
            if start < n_pieces:          # buffer full
                if fill == 0:             # one piece holds more steps than the buffer: grow it
                    size = max(need, 2 * len(buf_t))
                    self._buf_t[si] = np.empty(size, np.float64)
                    self._buf_d[si] = np.empty(size, np.int8)
                else:
                    self._flush(si)

    def _flush(self, si: int) -> None:
        fill = self._fill[si]
        if fill == 0:
            return
        times = self._buf_t[si][:fill]
        dirs = self._buf_d[si][:fill]
        if self.sds_filter_t is not None:
            out_t = np.empty(fill, np.float64)
            out_d = np.empty(fill, np.int8)
            m = kernel.sds_filter(times, dirs, self.sds_filter_t, self._sds[si], out_t, out_d)
            times, dirs = out_t[:m], out_d[:m]
        self._emit(si, times, dirs)
        self._fill[si] = 0

    def _emit(self, si: int, times: np.ndarray, dirs: np.ndarray) -> None:
        if len(times):
            kernel.step_stats(times, dirs, self.stats[si])
            self.sink(si, times, dirs)

    def finish(self) -> None:
        """Flush every buffer (and the step the filter holds back) to the sink."""
        for si in range(len(self.rails)):
            self._flush(si)
            if self.sds_filter_t is not None:
                t, d = kernel.sds_flush(self._sds[si])
                self._emit(si, t, d)


def generate_steps(segments: np.ndarray | Iterable[np.ndarray], machine=None, *, rails: list[Rail] | None = None,
                   klipper_names: bool = False, sds_filter_t: float | None = None,
                   reset: np.ndarray | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """All step times in memory: {stepper name: (times s, dirs int8)}. For tests and small files.

    ``segments`` is one SEGMENT array or an iterable of batches (``reset`` only
    applies to a single array). Steppers come from ``rails`` or from the machine.
    """
    if rails is None:
        rails = rails_for(machine, klipper_names)
    parts: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in rails]

    def sink(si, t, d):
        parts[si].append((t.copy(), d.copy()))

    gen = StepGenerator(rails, sink, sds_filter_t=sds_filter_t)
    if isinstance(segments, np.ndarray):
        gen.feed(segments, reset)
    else:
        for batch in segments:
            gen.feed(batch)
    gen.finish()
    out = {}
    for rail, chunks in zip(rails, parts):
        if chunks:
            out[rail.name] = (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]))
        else:
            out[rail.name] = (np.empty(0, np.float64), np.empty(0, np.int8))
    return out
