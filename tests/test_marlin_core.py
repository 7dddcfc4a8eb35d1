"""Marlin's COREXY / COREXZ builds: blocks, limits and pulses per motor (planner.cpp, CORE_IS_XY / CORE_IS_XZ).

Independent truth, worked by hand from planner.cpp: on a CoreXY machine a head move with ΔX = ΔY = D drives motor A
(X + Y) by 2·D and motor B (X − Y) not at all; the block Marlin builds in motor steps (step count, rates, the
acceleration in steps/s², the motors' speeds that classic jerk compares) is the block a cartesian Marlin builds
for an X move of 2·D at the same feed cap — so the times and A's pulses are those of that X move. A pure X move
drives A and B alike, each as X would on a cartesian machine with the same limits on both motors. The head
length (√2·D) is what the feed rate F applies to. "The same" is up to Marlin's float32 rounding of the two
computations (speeds from √2·D and from 2·D): one step/s in a rate, microseconds over a move.
"""
from __future__ import annotations

import numpy as np
import pytest

import gcodeplan as gp


def _machine(kinematics: str, **axes):
    m = gp.load_machine("marlin")
    m.kinematics = kinematics
    for ax in ("x", "y", "z"):
        m.axes[ax].position_min, m.axes[ax].position_max = -500.0, 500.0
    for ax, spm in axes.items():
        m.axes[ax].steps_per_mm = spm
    return m


def _write(tmp_path, name, lines):
    p = tmp_path / name
    p.write_text("G90\n" + "\n".join(lines) + "\n")
    return str(p)


def test_corexy_diagonal_runs_as_the_cartesian_x_move_of_the_motor_a(tmp_path):
    # feeds above motor A's 200 mm/s cap on both (A runs √2·F on the diagonal, F on X): the cap decides alike
    diag = _write(tmp_path, "diag.gcode", ["G1 X50 Y50 F12000", "G1 X0 Y0 F12000", "G1 X80 Y80 F12000",
                                           "G1 X10 Y10 F12000"])
    xonly = _write(tmp_path, "x.gcode", ["G1 X100 F12000", "G1 X0 F12000", "G1 X160 F12000", "G1 X20 F12000"])
    cxy = gp.estimate(diag, machine=_machine("corexy"))
    cart = gp.estimate(xonly, machine=_machine("cartesian"))
    assert cxy.total_time_s == pytest.approx(cart.total_time_s, rel=1e-5)
    assert np.allclose(np.asarray(cxy.line_times())[:, 1], np.asarray(cart.line_times())[:, 1], rtol=0, atol=5e-5)
    # and not the cartesian time of the diagonal: there the 200 mm/s cap is per axis, so the head runs √2 faster
    flat = gp.estimate(diag, machine=_machine("cartesian"))
    assert flat.total_time_s < 0.8 * cxy.total_time_s


def test_corexy_diagonal_pulses_are_motor_a_alone(tmp_path):
    diag = _write(tmp_path, "diag.gcode", ["G1 X50 Y50 F12000", "G1 X0 Y0 F12000", "G1 X80 Y80 F12000"])
    xonly = _write(tmp_path, "x.gcode", ["G1 X100 F12000", "G1 X0 F12000", "G1 X160 F12000"])
    cxy = gp.steps(diag, _machine("corexy"))
    cart = gp.steps(xonly, _machine("cartesian"))
    a_t, a_d = cxy["a"]
    x_t, x_d = cart["x"]
    assert len(a_t) == 2 * 100 * (50 + 50 + 80)          # 100 steps/mm, |ΔA| = 2·|ΔX| per move
    assert np.array_equal(a_d, x_d) and np.max(np.abs(a_t - x_t)) < 5e-5
    assert len(cxy["b"][0]) == 0


def test_corexy_pure_x_move_drives_both_motors_as_x(tmp_path):
    prog = ["G1 X50 F12000", "G1 X5 F6000", "G1 X40 F1200", "G1 X0 F9000"]
    cxy_path = _write(tmp_path, "x.gcode", prog)
    cxy = gp.estimate(cxy_path, machine=_machine("corexy"))
    cart = gp.estimate(cxy_path, machine=_machine("cartesian"))
    assert cxy.total_time_s == cart.total_time_s
    st = gp.steps(cxy_path, _machine("corexy"))
    xs = gp.steps(cxy_path, _machine("cartesian"))["x"]
    for motor in ("a", "b"):
        assert np.array_equal(st[motor][0], xs[0]) and np.array_equal(st[motor][1], xs[1])


def test_corexy_pure_y_move_runs_the_motors_against_each_other(tmp_path):
    path = _write(tmp_path, "y.gcode", ["G1 Y50 F12000", "G1 Y0 F12000"])
    st = gp.steps(path, _machine("corexy"))
    ys = gp.steps(path, _machine("cartesian"))["y"]
    assert np.array_equal(st["a"][0], ys[0]) and np.array_equal(st["a"][1], ys[1])     # A = X + Y
    assert np.array_equal(st["b"][0], ys[0]) and np.array_equal(st["b"][1], -ys[1])  # B = X − Y: reversed


def test_corexz_diagonal_runs_as_the_x_move_of_motor_a(tmp_path):
    # COREXZ with the X steps/mm on Z (a Core machine's A and C motors are alike)
    def core_xz(kin):
        m = _machine(kin, z=100.0)
        m.axes["z"].max_velocity, m.axes["z"].max_accel, m.axes["z"].jerk = (m.axes["x"].max_velocity,
                                                                             m.axes["x"].max_accel,
                                                                             m.axes["x"].jerk)
        return m

    diag = _write(tmp_path, "xz.gcode", ["G1 X50 Z50 F12000", "G1 X0 Z0 F12000"])
    xonly = _write(tmp_path, "x.gcode", ["G1 X100 F12000", "G1 X0 F12000"])
    assert gp.estimate(diag, machine=core_xz("corexz")).total_time_s == \
        gp.estimate(xonly, machine=core_xz("cartesian")).total_time_s
    st = gp.steps(diag, core_xz("corexz"))
    xs = gp.steps(xonly, core_xz("cartesian"))["x"]
    assert np.array_equal(st["a"][0], xs[0])
    assert len(st["b"][0]) == 0 and len(st["y"][0]) == 0


@pytest.mark.parametrize("policy", [None, "junction-deviation"])
def test_corexy_net_steps_follow_the_head(tmp_path, policy):
    # whatever the junction rule, each motor's net steps are its weights over the head's net steps
    path = _write(tmp_path, "zig.gcode", ["G1 X10 Y3 F6000", "G1 X-7 Y12", "G1 X21.37 Y-4.5", "G1 X3 Y3 F1500"])
    st = gp.steps(path, _machine("corexy"), policy=policy)
    net = {k: int(np.sum(np.where(d > 0, 1, -1))) for k, (t, d) in st.items() if len(t)}
    assert net["a"] == round(3 * 100) + round(3 * 100)
    assert net["b"] == 0
    # every pulse is in time order and the run ends when the estimate says
    est = gp.estimate(path, machine=_machine("corexy"), policy=policy)
    for t, _ in st.values():
        assert np.all(np.diff(t) >= 0)
        assert len(t) == 0 or t[-1] <= est.total_time_s + 1e-9


def test_a_delta_machine_is_refused_not_planned_as_cartesian(tmp_path):
    # Marlin cuts a delta's moves into segments (DELTA_SEGMENTS_PER_SECOND) and plans tower steps: not modelled,
    # so the model says so instead of timing the machine as a cartesian one
    from gcodeplan.errors import ConfigError

    m = gp.load_machine("marlin")
    m.kinematics = "delta"
    m.delta_radius, m.print_radius, m.delta_arm_length = 196.0, 202.0, (400.0, 400.0, 400.0)
    m.delta_position_endstop, m.delta_steps_per_mm = (300.0, 300.0, 300.0), (80.0, 80.0, 80.0)
    for ax in "xyz":
        m.axes[ax].position_min, m.axes[ax].position_max = -300.0, 300.0
    path = _write(tmp_path, "d.gcode", ["G1 X10 Y10 F3000"])
    with pytest.raises(ConfigError, match="kinematics 'delta' is not modelled"):
        gp.estimate(path, machine=m)
    m.firmware = "generic"
    assert gp.estimate(path, machine=m).total_time_s > 0
