"""grbl 1.1h stops the motion before a line that changes the work offset or writes its EEPROM (config.h's default
FORCE_BUFFER_SYNC_DURING_WCO_CHANGE and FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE; gcode.c gc_execute_line steps 14,
15 and 19), and not for M1 (gcode.c: "Optional stop not supported. Ignore.").

The independent truth: such a line costs exactly what a ``G4 P0`` there costs (grbl's dwell drains the planner the
same way, mc_dwell → protocol_buffer_synchronize) when it leaves the positions where they were, and a line that does
not stop costs nothing: the program times the same as without it.
"""
from __future__ import annotations

import pytest

import gcodeplan as gp

HEAD = "G21 G90\nG1 X10 Y5 F1200\n"
TAIL = "G1 X20 Y8\nG1 X30 Y12\n"


def _total(tmp_path, middle: str) -> float:
    path = tmp_path / "p.nc"
    path.write_text(HEAD + middle + TAIL)
    return gp.estimate(str(path), gp.load_machine("grbl")).total_time_s


@pytest.mark.parametrize("line", ["G92 X10 Y5", "G92.1", "G55", "G10 L2 P3 X1", "G10 L20 P2 X0", "G28.1", "G30.1",
                                  "G43.1 Z1.5", "G54 G43.1 Z0.2"])
def test_a_line_that_changes_the_work_offset_stops_as_a_dwell_does(tmp_path, line):
    stop = _total(tmp_path, "G4 P0\n")
    assert _total(tmp_path, line + "\n") == pytest.approx(stop, rel=0, abs=1e-12)
    assert stop > _total(tmp_path, "") + 0.01       # the stop is real: the corner at X10 Y5 is taken at rest


@pytest.mark.parametrize("line", ["M1", "G54", "G43.1 Z0", "G49", "G90"])
def test_a_line_that_changes_no_offset_does_not_stop(tmp_path, line):
    assert _total(tmp_path, line + "\n") == pytest.approx(_total(tmp_path, ""), rel=0, abs=1e-12)


def test_g49_after_an_offset_stops_twice(tmp_path):
    """G43.1 then G49: two changes of the tool length offset, two stops — the same as two dwells."""
    assert _total(tmp_path, "G43.1 Z2\nG1 X12 Y6\nG49\n") == pytest.approx(
        _total(tmp_path, "G4 P0\nG1 X12 Y6\nG4 P0\n"), rel=0, abs=1e-12)


def test_m1_still_pauses_on_linuxcnc_and_marlin(tmp_path):
    """Only grbl ignores M1: LinuxCNC's optional stop and Marlin's M1 (= M0) stop the machine."""
    for machine, suffix in (("linuxcnc", ".ngc"), ("marlin", ".gcode")):
        path = tmp_path / ("m1" + suffix)
        body = "G21 G90\nG1 X10 Y5 F1200\nM1\nG1 X20 Y8\n"
        path.write_text(body)
        with_m1 = gp.estimate(str(path), gp.load_machine(machine)).total_time_s
        path.write_text(body.replace("M1\n", ""))
        assert with_m1 > gp.estimate(str(path), gp.load_machine(machine)).total_time_s
