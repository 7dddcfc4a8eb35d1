"""``$N=value`` lines in a program on the grbl-1.1 model (gcode/grbl_line.py _grbl_setting).

Truth: grbl 1.1h's system.c system_execute_line stores a setting only when the machine is idle (else error:8,
the setting unchanged) and settings.c takes the new value for the blocks planned after it. So a setting
applied at the program's start, or after a line that syncs (G4, a spindle change), gives exactly the time of
the same program without the line on a machine that has the value from the start (the blocks before it do not
depend on it); a setting after a motion line is rejected and changes nothing. One case is also worked by hand:
a 100 mm G0 from rest to rest at $110 = 3000 mm/min and 500 mm/s² is 100/50 + 50/500 = 2.1 s, grbl's timer
rounding makes it 2.10053 s (the reference README's hand calculation of the same block at F3000).
"""
from __future__ import annotations

from dataclasses import replace

import pytest

import gcodeplan as gp

from conftest import shared_path


def _machine(**axis_x):
    """grbl-sim's settings ($1 = 255, $110 = 6000 mm/min, $120 = 500 mm/s²), X changed by ``axis_x``."""
    m = gp.load_machine(str(shared_path("reference", "grbl", "grbl_settings.txt")))
    if axis_x:
        axes = dict(m.axes)
        axes["x"] = replace(axes["x"], **axis_x)
        m = replace(m, axes=axes)
    return m


def _estimate(tmp_path, text: str, m, name="p.gcode"):
    p = tmp_path / name
    p.write_text(text)
    return gp.estimate(str(p), m)


def test_a_rate_set_at_the_start_is_the_machines_and_the_hand_worked_time(tmp_path):
    est = _estimate(tmp_path, "$110=3000\nG21 G90\nG0 X100\nM2\n", _machine())
    same = _estimate(tmp_path, "G21 G90\nG0 X100\nM2\n", _machine(max_velocity=50.0), "q.gcode")
    assert est.total_time_s == same.total_time_s
    v, a = 3000 / 60.0, 500.0
    assert 100.0 / v + v / a == pytest.approx(2.1)                    # the ideal trapezoid, closed form
    assert est.total_time_s == pytest.approx(2.10053, abs=1e-5)       # grbl's, as its G1 X100 F3000
    assert not any("$110" in w for w in est.parse.warnings)


def test_a_rate_set_while_grbl_moves_is_its_error_8_and_changes_nothing(tmp_path):
    text = "G21 G90\nG1 X10 F1000\n$110=3000\nG0 X100\nM2\n"
    est = _estimate(tmp_path, text, _machine())
    without = _estimate(tmp_path, text.replace("$110=3000\n", "(no setting)\n"), _machine(), "q.gcode")
    assert est.total_time_s == without.total_time_s
    assert any(":3:" in w and "error:8" in w for w in est.parse.warnings)


@pytest.mark.parametrize("sync", ["G4 P0", "M3 S1000", "M8"])
def test_a_rate_set_after_a_sync_applies_from_there(tmp_path, sync):
    text = f"G21 G90\nG1 X10 F1000\n{sync}\n$110=3000\nG0 X110\nM2\n"
    est = _estimate(tmp_path, text, _machine())
    # G1 at 1000 mm/min is below both rates: only the G0 after the setting depends on it
    same = _estimate(tmp_path, text.replace("$110=3000\n", ""), _machine(max_velocity=50.0), "q.gcode")
    old = _estimate(tmp_path, text.replace("$110=3000\n", ""), _machine(), "r.gcode")
    assert est.total_time_s == same.total_time_s
    assert est.total_time_s > old.total_time_s + 0.9       # 100 mm at 50 instead of 100 mm/s
    assert not any("error:8" in w for w in est.parse.warnings)


def test_a_line_that_moves_nowhere_keeps_grbl_idle(tmp_path):
    """G0 X0 at X0 makes no block (planner.c: zero steps), so grbl is still idle at the setting."""
    text = "G21 G90\nG0 X0\n$120=100\nG1 X50 F3000\nM2\n"
    est = _estimate(tmp_path, text, _machine())
    same = _estimate(tmp_path, text.replace("$120=100\n", ""), _machine(max_accel=100.0), "q.gcode")
    assert est.total_time_s == same.total_time_s


def test_junction_deviation_arc_tolerance_and_laser_mode_apply(tmp_path):
    body = "G21 G90 F2000\nG1 X10\nY10\nG2 X20 Y20 I10 J0\nM4 S100\nG1 X30 S200\nG1 X40 S300\nM5\nM2\n"
    base = _machine()
    for line, m in (("$11=0.1", replace(base, junction_deviation=0.1)),
                    ("$12=0.05", replace(base, arc_tolerance=0.05)),
                    ("$32=1", replace(base, grbl_laser_mode=1))):
        est = _estimate(tmp_path, line + "\n" + body, base)
        same = _estimate(tmp_path, body, m, "q.gcode")
        old = _estimate(tmp_path, body, base, "r.gcode")
        assert est.total_time_s == same.total_time_s != old.total_time_s, line


def test_settings_not_applied_are_named(tmp_path):
    est = _estimate(tmp_path, "$100=100\n$1=10\n$110=-5\nG21 G90\nG0 X10\nM2\n", _machine())
    warns = est.parse.warnings
    assert any("$100" in w and "not applied" in w for w in warns)
    assert any("$1=10" in w and "not applied" in w for w in warns)
    assert any(":3:" in w and "error:4" in w for w in warns)
    assert est.total_time_s == _estimate(tmp_path, "G21 G90\nG0 X10\nM2\n", _machine(), "q.gcode").total_time_s
    from gcodeplan.errors import GcodeError

    with pytest.raises(GcodeError, match="p.gcode.*1"):
        gp.estimate(str(tmp_path / "p.gcode"), _machine(), strict=True)
    with pytest.raises(GcodeError, match="rate or acceleration of 0"):
        _estimate(tmp_path, "$110=0\nG0 X10\n", _machine())


def test_a_grbl_flavor_machine_on_a_policy_takes_the_setting_too(tmp_path):
    """On a machine with grbl's G-code but a generic planner, the new limit is the planner's from there on."""
    m = replace(_machine(), firmware="generic")
    est = _estimate(tmp_path, "$110=3000\nG21 G90\nG0 X100\nM2\n", m)
    same = _estimate(tmp_path, "G21 G90\nG0 X100\nM2\n", replace(_machine(max_velocity=50.0), firmware="generic"),
                     "q.gcode")
    assert est.total_time_s == pytest.approx(same.total_time_s, rel=1e-12)
