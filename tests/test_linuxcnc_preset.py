"""The ``linuxcnc`` preset: the mill of the LinuxCNC reference runs, by name (``--machine linuxcnc``)."""
from __future__ import annotations

import json

import pytest

from conftest import SAMPLES, shared_path
import gcodeplan as gp
from gcodeplan.cli import main

REF = ("reference", "linuxcnc")


def _noidle(stem: str) -> float:
    return json.loads(shared_path(*REF, "times.json").read_text())[stem]["total_time_noidle_s"]


@pytest.mark.parametrize("program,stem", [("linuxcnc_plasmatest.ngc", "linuxcnc_plasmatest_g64"),
                                          ("linuxcnc_arcspiral.ngc", "linuxcnc_arcspiral_g64")])
def test_preset_plans_as_linuxcnc_ran_the_reference_mill(program, stem):
    m = gp.load_machine("linuxcnc")
    assert (m.flavor, m.firmware, m.junction_policy) == ("linuxcnc", "linuxcnc", "linuxcnc")
    est = gp.estimate(str(SAMPLES / program), machine=m)
    ref = _noidle(stem)
    # LinuxCNC 2.9's own time for the program on that mill, as tests/test_linuxcnc.py holds the ini to
    assert abs(est.total_time_s - ref) <= 0.005 * ref
    # and exactly what the reference's mill.ini gives
    mill = gp.load_machine(str(shared_path(*REF, "config", "mill.ini")))
    assert est.total_time_s == gp.estimate(str(SAMPLES / program), machine=mill).total_time_s


def test_preset_is_listed_and_named_in_the_summary(capsys):
    assert "linuxcnc" in gp.config.preset_names()
    assert main(["estimate", "--machine", "linuxcnc", str(SAMPLES / "linuxcnc_arcspiral.ngc")]) == 0
    out = capsys.readouterr().out
    assert "machine linuxcnc-3axis-mill, firmware linuxcnc (LinuxCNC 2.9)" in out


def test_axis_limits_are_linuxcncs_ini_values():
    m = gp.load_machine("linuxcnc")
    assert (m.max_velocity, m.max_accel) == (100.0, float("inf"))
    assert [(m.axes[a].max_velocity, m.axes[a].max_accel) for a in "xyz"] == [(100.0, 1000.0), (100.0, 1000.0),
                                                                                (20.0, 500.0)]
