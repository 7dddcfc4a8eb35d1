"""Compact step files: lossless (the very same float64 times and directions), far smaller, both forms
read by one loader; Klipper's reference files read by it too."""
from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import SAMPLES, shared_path
from gcodeplan.cli import main
from gcodeplan.stepper.export import (COMPACT_FORMAT, CompactEncoder, decode_compact, load_npz, load_steps,
                                      pack_time_planes, unpack_time_planes)


def _encode(chunks, level=6):
    enc = CompactEncoder(level)
    tz, dz = [], []
    for t, d in chunks:
        a, b = enc.feed(t, d)
        tz.append(a)
        dz.append(b)
    a, b = enc.finish()
    tz.append(a)
    dz.append(b)
    return (np.frombuffer(b"".join(tz), np.uint8), np.frombuffer(b"".join(dz), np.uint8), enc.blocks, enc.widths)


_times = st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=60).map(
    lambda v: np.array(v, np.float64))


@settings(max_examples=300, deadline=None)
@given(parts=st.lists(_times, max_size=6), seed=st.integers(0, 2**32 - 1))
def test_any_float64_times_come_back_bit_for_bit(parts, seed):
    """Any bit patterns (negative, decreasing, NaN payloads, ±0, inf), chunked anyhow, empty chunks too."""
    rng = np.random.default_rng(seed)
    chunks = [(t, rng.choice(np.array([-1, 1], np.int8), len(t))) for t in parts]
    t, d = decode_compact(*_encode(chunks))
    want_t = np.concatenate([c[0] for c in chunks]) if chunks else np.zeros(0)
    want_d = np.concatenate([c[1] for c in chunks]) if chunks else np.zeros(0, np.int8)
    assert np.array_equal(t.view(np.int64), want_t.view(np.int64)) and np.array_equal(d, want_d)
    assert d.dtype == np.int8 and t.dtype == np.float64


def test_planes_by_hand():
    """Differences 3, −1, 0 from 0 → zigzag 6, 1, 0: one byte plane; a difference of 2**40 needs six."""
    k, planes = pack_time_planes(np.array([3, 2, 2], np.int64), np.int64(0))
    assert k == 1 and list(planes) == [6, 1, 0]
    k, planes = pack_time_planes(np.array([2**40], np.int64), np.int64(0))
    assert k == 6 and list(planes) == [0, 0, 0, 0, 0, 2]
    out = np.empty(1, np.int64)
    assert unpack_time_planes(planes, 6, 1, np.int64(0), out) == 2**40 and out[0] == 2**40


def test_bad_directions_are_refused():
    with pytest.raises(ValueError, match=r"\+1 or -1"):
        CompactEncoder().feed(np.ones(3), np.array([1, 0, -1], np.int8))


def test_damaged_file_is_a_clear_error():
    tz, dz, blocks, widths = _encode([(np.arange(10.0), np.ones(10, np.int8))])
    from gcodeplan.errors import GcodeplanError

    with pytest.raises(GcodeplanError, match="damaged"):
        decode_compact(tz, dz, [11], widths)


def _steps_both(tmp_path, gcode, *extra):
    plain, compact = tmp_path / "plain.npz", tmp_path / "compact.npz"
    assert main(["steps", str(gcode), "-o", str(plain), "-q", *extra]) == 0
    assert main(["steps", str(gcode), "-o", str(compact), "-q", "--format", "compact", *extra]) == 0
    return plain, compact


def test_compact_and_plain_files_load_to_the_same_steps(tmp_path):
    plain, compact = _steps_both(tmp_path, SAMPLES / "d_slicer_like.gcode", "--compress")
    a, b = load_steps(plain), load_steps(compact)
    assert list(a) == list(b) == ["x", "y", "z", "e"]
    for name in a:
        assert np.array_equal(a[name][0], b[name][0]) and np.array_equal(a[name][1], b[name][1])
        assert a[name][0].dtype == np.float64 and a[name][1].dtype == np.int8 and len(a[name][0]) > 0
    raw = load_npz(compact)
    assert str(raw["format"]) == COMPACT_FORMAT and "x" not in raw and "x_runs" in raw     # --compress kept
    assert sorted(n for n in os.listdir(tmp_path) if n.startswith(".")) == []


def test_load_steps_reads_klippers_reference_files():
    ref = shared_path("reference", "klipper", "synthetic", "a_long_x_cartesian_exact_steps.npz")
    steps = load_steps(ref)
    raw = np.load(ref)
    assert list(steps) == ["extruder", "stepper_x", "stepper_y", "stepper_z"]
    assert np.array_equal(steps["stepper_x"][0], raw["stepper_x"])


def test_compact_is_more_than_4x_smaller_on_the_cube(tmp_path):
    plain, compact = _steps_both(tmp_path, shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode"))
    ratio = plain.stat().st_size / compact.stat().st_size
    assert ratio > 4, ratio
    a, b = load_steps(plain), load_steps(compact)
    assert all(np.array_equal(a[k][0], b[k][0]) and np.array_equal(a[k][1], b[k][1]) for k in a)


@pytest.mark.slow
def test_compact_is_more_than_4x_smaller_on_the_50mb_file(tmp_path):
    plain, compact = _steps_both(tmp_path, shared_path("gcode", "prusaslicer25_plate150_gyroid_big.gcode"))
    assert plain.stat().st_size / compact.stat().st_size > 4
    b = load_steps(compact)
    with np.load(plain) as z:
        for name in b:
            assert np.array_equal(z[name], b[name][0]) and np.array_equal(z[name + "_dir"], b[name][1])
