"""PLAN rows of the grbl 1.1 model have no phase of negative time: a block grbl plans as one deceleration
from its entry can get, in single precision, a top speed one float below its entry speed (its
accelerate/decelerate intersection falls just inside the block); the profile's peak is then its entry.
Checked on a hand-picked case and on every grbl reference program (R and I/J arcs, lines), whose totals stay
grbl 1.1h's own (../shared/reference/grbl, grbl-sim)."""
from __future__ import annotations

import json

import numpy as np
import pytest

import gcodeplan as gp

from conftest import shared_path

PHASES = ("accel_t", "cruise_t", "decel_t")

# lines 11390-11396 of the 50 MB PrusaSlicer plate (E words removed): the 0.08 mm move at F900 decelerates
# over its whole length to the sharp corner after it; its top speed √(2·a·intersect + exit²) came out one
# float32 below its entry and its PLAN row had accel_t = −1.7e-9 s
DECELERATING_BLOCK = [
    "G21 G90",
    "G0 X59.025 Y45.99 Z.35",
    "G1 F900",
    "G1 X58.947 Y44.805",
    "G1 X59.101 Y43.628",
    "G1 X59.482 Y42.503",
    "G1 X59.522 Y42.435",
    "G1 X59.912 Y42.582 F10800",
]


def _assert_phases_cover_rows(plan, moves):
    for f in PHASES:
        assert np.all(plan[f] >= 0), f
    moving = (moves["kind"] <= 1) & (plan["duration"] > 0)
    total = plan["accel_t"] + plan["cruise_t"] + plan["decel_t"]
    assert np.allclose(total[moving], plan["duration"][moving], rtol=1e-9)
    assert np.all(plan["cruise_v"][moving] >= plan["start_v"][moving])
    assert np.all(plan["cruise_v"][moving] >= plan["end_v"][moving])


def test_a_block_decelerating_from_its_entry_has_no_negative_acceleration_time():
    p = gp.plan(DECELERATING_BLOCK, "grbl")
    _assert_phases_cover_rows(p.plan, p.moves)
    row = int(np.nonzero(p.moves["line"] == 7)[0][0])
    pl = p.plan[row]
    # the block is one deceleration: no acceleration, its peak is its entry, and it ends slower
    assert pl["accel_t"] == 0.0 and pl["cruise_v"] == pl["start_v"] and pl["end_v"] < pl["start_v"]


@pytest.mark.parametrize("name", ["synth_square", "synth_polycircle30", "synth_arcs", "linuxcnc_plasmatest",
                                  "linuxcnc_arcspiral"])
def test_reference_programs_have_no_negative_phase_and_grbl_s_total(tmp_path, name):
    """Every phase time ≥ 0 on grbl-sim's programs (synth_arcs: G2/G3 with R and with I/J), the total the
    firmware's own (the time of its last step pulse, to its 62.5 ns tick; the reference prints 7 decimals)."""
    entry = json.loads(shared_path("reference", "grbl", "times.json").read_text())[name]
    lines = shared_path(*entry["program"].split("/")[1:]).read_text().split("\n")
    for edit in entry["preprocessing"]:        # the lines grbl rejects (README, Preprocessing)
        lines[edit["line"] - 1] = edit["after"]
    program = tmp_path / "program.gcode"
    program.write_text("\n".join(lines))
    p = gp.plan(str(program), gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt"))))
    _assert_phases_cover_rows(p.plan, p.moves)
    assert p.plan["t_start"][-1] + p.plan["duration"][-1] == pytest.approx(entry["total_time_s"], abs=2e-7)
