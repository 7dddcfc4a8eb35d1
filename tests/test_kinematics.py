"""Kinematics: stepper names, steps/mm and the axis → stepper transform."""
from __future__ import annotations

import numpy as np
import pytest

from gcodeplan.errors import ConfigError
from gcodeplan.kinematics import rails_for, stepper_pieces
from gcodeplan.machine import Machine
from gcodeplan.stepper.synth import line_segments, scurve_line_segments


def machine(kin: str) -> Machine:
    m = Machine(kinematics=kin)
    m.axes["x"].steps_per_mm = 80.0
    m.axes["y"].steps_per_mm = 100.0
    m.axes["z"].steps_per_mm = 400.0
    m.axes["e"].steps_per_mm = 95.52
    return m


def test_names_and_steps_per_mm():
    assert [r.name for r in rails_for(machine("cartesian"))] == ["x", "y", "z", "e"]
    assert [r.name for r in rails_for(machine("corexy"))] == ["a", "b", "z", "e"]
    klip = rails_for(machine("corexy"), klipper_names=True)
    assert [r.name for r in klip] == ["stepper_x", "stepper_y", "stepper_z", "extruder"]
    # Klipper: stepper_x (A) and stepper_y (B) each take their own section's steps
    assert [r.steps_per_mm for r in klip] == [80.0, 100.0, 400.0, 95.52]
    assert klip[2].step_dist == pytest.approx(0.0025)


def test_unknown_kinematics_and_bad_steps_are_config_errors():
    with pytest.raises(ConfigError, match="delta"):
        rails_for(Machine(kinematics="delta"))
    m = machine("cartesian")
    m.axes["y"].steps_per_mm = 0.0
    with pytest.raises(ConfigError, match="y: steps_per_mm"):
        rails_for(m)


def test_cartesian_pieces_are_the_planner_coefficients_bit_for_bit():
    seg = line_segments((1.5, -2.0, 0.2, 3.0), (101.25, 40.0, 0.6, 7.5), 3.0, 120.0, 5.0, 2500.0)
    for rail, ax in zip(rails_for(machine("cartesian")), "xyze"):
        t0, dt, p, v, a, j = stepper_pieces(seg, rail)
        assert np.array_equal(p, seg["p" + ax]) and np.array_equal(v, seg["v" + ax])
        assert np.array_equal(a, seg["a" + ax]) and np.array_equal(j, seg["j" + ax])
        assert np.array_equal(t0, seg["t0"]) and np.array_equal(dt, seg["dt"])


@pytest.mark.parametrize("builder", ["trapezoid", "scurve"])
def test_corexy_is_sum_and_difference_at_every_time(builder):
    if builder == "trapezoid":
        seg = line_segments((10, 20, 0, 0), (-30, 65, 0, 0), 0.0, 150.0, 0.0, 3000.0)
    else:
        seg = scurve_line_segments((10, 20, 0, 0), (-30, 65, 0, 0), 150.0, 3000.0, 1e5)
    a_rail, b_rail = rails_for(machine("corexy"))[:2]
    pa = stepper_pieces(seg, a_rail)
    pb = stepper_pieces(seg, b_rail)
    rng = np.random.default_rng(1)
    for i in range(len(seg)):
        for tau in rng.uniform(0, seg["dt"][i], 5):
            def at(c, ax=None):
                if ax is None:
                    p, v, a, j = c[2][i], c[3][i], c[4][i], c[5][i]
                else:
                    p, v, a, j = (seg[k + ax][i] for k in "pvaj")
                return p + v * tau + a * tau ** 2 / 2 + j * tau ** 3 / 6
            x, y = at(None, "x"), at(None, "y")
            assert at(pa) == pytest.approx(x + y, abs=1e-12)
            assert at(pb) == pytest.approx(x - y, abs=1e-12)
