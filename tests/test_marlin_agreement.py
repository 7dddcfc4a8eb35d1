"""Marlin / PrusaSlicer agreement: PrusaSlicer files carry their machine limits (M201/M203/M204/M205 in
the header) and PrusaSlicer's own estimate of Marlin's classic-jerk planner in a comment. With the
marlin preset (Marlin meanings: M204 P/T/R, M205 jerk honoured) our classic-jerk total must be within
2 % of theirs.

Measured on this corpus (gcodeplan estimate --machine marlin --policy classic-jerk FILE: the marlin preset
runs the marlin-2.1.2 firmware model, Marlin's own classic jerk, 1130.895 s for the cube as Marlin 2.1.2.4):
cube -1.66 %, vase -0.07 %, multi-object -1.13 %, gyroid plate -1.90 % (PrusaSlicer rounds to whole
seconds); with --firmware generic (gcodeplan's classic-jerk policy) -0.47 %, -0.01 %, -0.32 %, -0.76 %.
All are below the 2 % that would need explaining; where we differ we are faster, and PrusaSlicer's
estimator (its own re-implementation of Marlin's planner) is not the ground truth: Marlin 2.1.2.4's own code
gives the cube 1130.895 s (shared/reference/marlin), 1.66 % under PrusaSlicer's 1150 s.
"""
import pytest

from gcodeplan.config import load_machine
from gcodeplan.api import estimate
from conftest import SAMPLES, shared_path

BIG = ["prusaslicer25_twisted_vase_spiral.gcode", "prusaslicer25_multi_object_plate_relE.gcode",
       "prusaslicer25_plate150_gyroid_big.gcode"]


def _check(path):
    est = estimate(str(path), load_machine("marlin"), "classic-jerk")
    slicer = est.parse.slicer_estimate_s
    assert slicer, "PrusaSlicer writes its estimate in every file"
    assert est.time.total_time_s == pytest.approx(slicer, rel=0.02)
    return est.time.total_time_s, slicer


def test_cube_within_two_percent_of_prusaslicer():
    ours, theirs = _check(SAMPLES / "prusaslicer25_cube20_marlin2.gcode")
    assert theirs == 19 * 60 + 10  # "; estimated printing time (normal mode) = 19m 10s"


def test_file_limits_are_honoured_under_marlin_meanings(tmp_path):
    """The header's M201 (per-axis accel) governs under Marlin meanings, and Klipper ignores it."""
    text = (SAMPLES / "prusaslicer25_cube20_marlin2.gcode").read_text()
    assert "M201 X1000 Y1000" in text
    slow = tmp_path / "cube_slow_accel.gcode"
    slow.write_text(text.replace("M201 X1000 Y1000", "M201 X250 Y250", 1))
    base = estimate(str(SAMPLES / "prusaslicer25_cube20_marlin2.gcode"), load_machine("marlin"), "classic-jerk").time.total_time_s
    slower = estimate(str(slow), load_machine("marlin"), "classic-jerk").time.total_time_s
    assert slower > base * 1.02
    klipper = load_machine("klipper")
    k_base = estimate(str(SAMPLES / "prusaslicer25_cube20_marlin2.gcode"), klipper, None)
    k_slow = estimate(str(slow), klipper, None)
    assert k_slow.time.total_time_s == k_base.time.total_time_s
    assert k_slow.parse.ignored_commands.get("M201") == 1


@pytest.mark.slow
@pytest.mark.parametrize("name", BIG)
def test_corpus_within_two_percent_of_prusaslicer(name):
    _check(shared_path("gcode", name))
