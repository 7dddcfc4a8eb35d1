"""The PLAN rows the Marlin model hands out (speeds and phase times, what plots, the viewer, sampling and the
summary's peak speed read): each row keeps the interrupt's duration and the move's length, and never runs faster
than the block's nominal speed — Marlin's interrupt holds the nominal rate once a ramp reaches it
(stepper.cpp: NOMORE(acc_step_rate, nominal_rate)), so a row read as straight ramps must not peak above it.
"""
from __future__ import annotations

import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES

PROGRAM = ("G21\nG90\nM83\nM201 X500 Y500\nM203 X100 Y100\nM204 P800 T1000\nM205 X8 Y8\n"
           "G1 X50 Y0 F6000\nG1 X50 Y50 E2\nM220 S150\nG1 X0 Y50\nG1 X0 Y0\nG1 X20 Y20\n")


def _rows(path):
    p = gp.plan(str(path), gp.load_machine("marlin"))
    return p.moves, p.plan


def _check_rows(moves, plan):
    """Every row with a block covers its move in its duration; a row merged into the next block (under 6 steps)
    passes in no time. Speeds stay at the feed, up to the rounding of Marlin's integer step rates (a short block
    enters at a rate rounded up: 1 % on the circle's 0.63 mm chords)."""
    moving = (moves["move_d"] > 0) & (plan["duration"] > 0)
    v0, vc, v1 = plan["start_v"], plan["cruise_v"], plan["end_v"]
    ta, tc, td = plan["accel_t"], plan["cruise_t"], plan["decel_t"]
    covered = (v0 + vc) / 2 * ta + vc * tc + (vc + v1) / 2 * td
    np.testing.assert_allclose(covered[moving], moves["move_d"][moving], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose((ta + tc + td)[moving], plan["duration"][moving], rtol=1e-12, atol=1e-15)
    assert (ta >= 0).all() and (tc >= 0).all() and (td >= 0).all()
    assert (vc[moving] <= moves["feed_v"][moving] * 1.02).all()


def test_a_diagonal_capped_by_m203_peaks_at_the_cap(tmp_path):
    """X20 Y20 at 150 mm/s (M220 S150) with M203 X100 Y100: 100·√2 mm/s at most (by hand); read as a triangle
    the interrupt's ramps would peak at 144.7 mm/s."""
    path = tmp_path / "cap.gcode"
    path.write_text(PROGRAM)
    moves, plan = _rows(path)
    _check_rows(moves, plan)
    last = plan[moves["line"] == 13][0]
    assert last["cruise_v"] == pytest.approx(100 * np.sqrt(2), rel=1e-6)
    assert last["cruise_t"] > 0
    straight = plan[np.isin(moves["line"], (8, 9, 11, 12))]
    assert np.allclose(straight["cruise_v"], 100.0, rtol=1e-9)        # M203's 100 mm/s, not 100.3


@pytest.mark.parametrize("name", ["prusaslicer25_cube20_marlin2.gcode", "c_circle200.gcode"])
def test_sample_rows_cover_their_moves_below_their_feed(name):
    _check_rows(*_rows(SAMPLES / name))
