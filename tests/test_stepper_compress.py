"""Step compression: decompressed steps stay within the error bound of the exact ones."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcodeplan.machine import Machine
from gcodeplan.stepper.compress import RUN_DTYPE, Compressor, compress_steps, decompress_runs
from gcodeplan.stepper.generate import generate_steps
from gcodeplan.stepper.synth import line_segments, polyline_segments

F = 50e6


def check_bound(times, dirs, runs, max_error, clock_hz=F):
    clocks, rdirs = decompress_runs(runs)
    assert len(clocks) == len(times)
    assert np.array_equal(rdirs, dirs)
    got = clocks / clock_hz
    early = times - got
    # never after Klipper's clock floor(t·f + ½), never more than the bound (+ the ½-tick rounding) early
    assert np.all(clocks <= np.floor(times * clock_hz + 0.5))
    assert np.max(early, initial=0.0) <= max_error + 0.5 / clock_hz + 1e-12
    assert np.min(early, initial=0.0) >= -0.5 / clock_hz - 1e-12
    assert np.all(np.diff(clocks) >= 0)


def test_decompress_formula_by_hand():
    runs = np.array([(100, 3, 10, 1), (7, 2, 0, -1)], RUN_DTYPE)
    clocks, dirs = decompress_runs(runs, start_clock=1000)
    # step k at last + k·interval + add·k(k−1)/2
    assert list(clocks) == [1100, 1210, 1330, 1337, 1344]
    assert list(dirs) == [1, 1, 1, -1, -1]


def test_constant_rate_is_one_run():
    times = np.arange(1, 5001) * 250e-6           # exactly 12500 ticks apart
    runs = compress_steps(times, np.ones(5000, np.int8))
    assert len(runs) == 1 and runs[0]["count"] == 5000 and runs[0]["interval"] == 12500
    assert runs[0]["add"] == 0


def test_zero_error_reproduces_klipper_clocks():
    seg = line_segments((0, 0, 0, 0), (20, 0, 0, 0), 0.0, 100.0, 0.0, 3000.0)
    m = Machine()
    t, d = generate_steps(seg, m)["x"]
    runs = compress_steps(t, d, max_error_s=0.0)
    clocks, _ = decompress_runs(runs)
    assert np.array_equal(clocks, np.floor(t * F + 0.5).astype(np.int64))


def test_accelerating_move_compresses_well():
    seg = line_segments((0, 0, 0, 0), (200, 0, 0, 0), 0.0, 100.0, 0.0, 3000.0)
    t, d = generate_steps(seg, Machine())["x"]
    runs = compress_steps(t, d)
    check_bound(t, d, runs, 25e-6)
    assert len(t) / len(runs) > 50       # a trapezoid is a handful of (interval, add) runs per ramp


def test_streaming_chunks_keep_the_bound():
    seg = polyline_segments([(0, 0, 0, 0), (40, 0, 0, 0), (0, 3, 0, 0), (25, 25, 0, 0)], 120.0, 2500.0,
                            junction_v=5.0)
    t, d = generate_steps(seg, Machine())["x"]
    comp = Compressor()
    runs = np.concatenate([comp.feed(t[i:i + 777], d[i:i + 777]) for i in range(0, len(t), 777)])
    check_bound(t, d, runs, 25e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(-60, 60), st.floats(-60, 60)), min_size=1, max_size=6),
       st.floats(5, 300), st.floats(100, 8000), st.floats(0, 30),
       st.sampled_from([0.0, 1e-6, 25e-6, 100e-6]), st.sampled_from(["cartesian", "corexy"]))
def test_random_plans_decompress_within_bound(points, max_v, accel, junction_v, max_error, kin):
    pts = [(0.0, 0.0, 0.0, 0.0)] + [(x, y, 0.0, 0.0) for x, y in points]
    seg = polyline_segments(pts, max_v, accel, junction_v=junction_v)
    steps = generate_steps(seg, Machine(kinematics=kin))
    for name, (t, d) in steps.items():
        runs = compress_steps(t, d, max_error_s=max_error)
        check_bound(t, d, runs, max_error)
        assert np.all(runs["count"] >= 1) and np.all(runs["count"] <= 65535)
        assert np.all(np.abs(runs["add"]) <= 32767)


def test_bad_parameters():
    with pytest.raises(ValueError):
        Compressor(clock_hz=0)
