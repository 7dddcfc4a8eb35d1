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


# ----------------------------------------------------------------- the linear plug-in (issue 9)

from gcodeplan.kinematics import Linear  # noqa: E402
from gcodeplan.stepper.generate import generate_steps  # noqa: E402
from gcodeplan.stepper.synth import polyline_segments  # noqa: E402


def _sample_plan():
    """A path with every sign of dx, dy, dz, de, corners and a full stop: exercises every weight."""
    pts = [(0, 0, 0, 0), (40, 10, 0, 2), (55, -20, 0.4, 3.5), (10, -35, 0.4, 3.0), (-5, 5, 1.0, 4.2), (0, 0, 0, 4.2)]
    return polyline_segments(pts, 150.0, 3000.0, junction_v=8.0)


@pytest.mark.parametrize("kin", ["cartesian", "corexy"])
def test_linear_recreates_the_builtins_step_for_step(kin):
    m = machine(kin)
    seg = _sample_plan()
    builtin = generate_steps(seg, m, klipper_names=True)
    w = {"cartesian": {"stepper_x": (1, 0, 0), "stepper_y": (0, 1, 0), "stepper_z": (0, 0, 1)},
         "corexy": {"stepper_x": (1, 1, 0), "stepper_y": (1, -1, 0), "stepper_z": (0, 0, 1)}}[kin]
    lin = Linear(w, steps_per_mm={"stepper_x": 80, "stepper_y": 100, "stepper_z": 400, "extruder": 95.52})
    ours = generate_steps(seg, m, kinematics=lin)
    assert list(ours) == list(builtin) == ["stepper_x", "stepper_y", "stepper_z", "extruder"]
    for name in builtin:
        assert np.array_equal(ours[name][0], builtin[name][0]), name
        assert np.array_equal(ours[name][1], builtin[name][1]), name
        assert len(builtin[name][0]) > 0


def test_linear_extruder_rail_and_steps_from_the_machine():
    m = machine("cartesian")
    lin = Linear({"stepper_a": (1, 1, 0), "stepper_b": (1, -1, 0), "stepper_z": (0, 0, 1)},
                 steps_per_mm={"stepper_a": 80})
    rails = lin.rails(m)
    assert [r.name for r in rails] == ["stepper_a", "stepper_b", "stepper_z", "extruder"]
    # unnamed motors take their first weighted axis's steps: B from x (80), Z from z (400), E from e
    assert [r.steps_per_mm for r in rails] == [80.0, 80.0, 400.0, 95.52]
    assert rails[-1].weights == (0.0, 0.0, 0.0, 1.0)
    # a mapping that drives E itself gets no automatic extruder; extruder=None drops it
    assert [r.name for r in Linear({"u": (1, 0, 0, 0.5)}, {"u": 10}).rails(m)] == ["u"]
    assert [r.name for r in Linear({"u": (1, 0, 0)}, {"u": 10}, extruder=None).rails(m)] == ["u"]


@pytest.mark.parametrize("bad, match", [
    ({}, "non-empty"),
    ({"a": (1, 0)}, "3 or 4"),
    ({"a": (0, 0, 0)}, "all weights are zero"),
    ({"a": (1, float("nan"), 0)}, "finite"),
])
def test_linear_rejects_bad_mappings(bad, match):
    with pytest.raises(ConfigError, match=match):
        Linear(bad, {})


def test_linear_rejects_bad_steps():
    with pytest.raises(ConfigError, match="unknown motor"):
        Linear({"a": (1, 0, 0)}, {"b": 80})
    with pytest.raises(ConfigError, match="positive"):
        Linear({"a": (1, 0, 0)}, {"a": -80})


def test_corexz_motors_follow_klippers_closed_form():
    """Klipper corexz.py: stepper_x = x + z, stepper_y = y, stepper_z = x − z; net steps = Δ·steps/mm."""
    m = machine("corexz")
    rails = rails_for(m, klipper_names=True)
    assert [r.name for r in rails] == ["stepper_x", "stepper_y", "stepper_z", "extruder"]
    # each motor its own section's step distance (Klipper): x 80, y 100, z 400
    assert [r.steps_per_mm for r in rails] == [80.0, 100.0, 400.0, 95.52]
    start, end = (3.0, 4.0, 1.0, 0.0), (23.0, -6.0, 6.0, 1.0)
    seg = line_segments(start, end, 0.0, 60.0, 0.0, 1500.0)
    steps = generate_steps(seg, m, klipper_names=True)
    dx, dy, dz = (e - s for s, e in zip(start[:3], end[:3]))
    for name, motor_d, spm in (("stepper_x", dx + dz, 80.0), ("stepper_y", dy, 100.0),
                               ("stepper_z", dx - dz, 400.0)):
        t, d = steps[name]
        assert int(d.sum()) == round(motor_d * spm), name
    # at every step the motor's closed-form position is on its half-step point
    t, d = steps["stepper_z"]
    n = np.cumsum(d)
    u = (t - seg["t0"][np.searchsorted(seg["t0"], t, side="right") - 1])
    k = np.searchsorted(seg["t0"], t, side="right") - 1
    pos = {ax: seg["p" + ax][k] + seg["v" + ax][k] * u + seg["a" + ax][k] * u ** 2 / 2 for ax in "xz"}
    motor = (pos["x"] - start[0]) - (pos["z"] - start[2])
    assert np.allclose(motor * 400.0, n - 0.5 * d, atol=1e-6)


def test_corexz_is_accepted_in_machine_files_and_klipper_configs(tmp_path):
    from gcodeplan.config import load_klipper_config, load_machine

    toml = tmp_path / "m.toml"
    toml.write_text('kinematics = "corexz"\n')
    assert load_machine(str(toml)).kinematics == "corexz"
    cfg = tmp_path / "printer.cfg"
    cfg.write_text("[printer]\nkinematics: corexz\nmax_velocity: 300\nmax_accel: 3000\n"
                   + "".join(f"[stepper_{a}]\nrotation_distance: 40\nmicrosteps: 16\nposition_endstop: 0\n"
                             for a in "xyz"))
    assert load_klipper_config(str(cfg)).kinematics == "corexz"
