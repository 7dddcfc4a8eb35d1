"""The axes plot of a plug-in kinematics (issue 22): each motor given by the plug-in's inverse kinematics gets a
row, its position in the motor's own unit (polar: the bed angle in rad, the arm in mm) and its velocity, like a
linear machine's motors. Checked against the polar geometry by hand: θ = atan2(y, x), r = √(x² + y²), and
their time derivatives θ' = (x·y' − y·x')/r², r' = (x·x' + y·y')/r."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.machine import Machine
from gcodeplan.report import plots
from test_plots import join, line_by_gid, trapezoid_move, xy


def polar_machine(**kw) -> Machine:
    m = Machine(kinematics="polar", flavor="klipper", max_velocity=300.0, max_accel=3000.0, **kw)
    m.kinematics_params = {"bed_steps_per_rad": 64000 / (2 * math.pi), "arm_steps_per_mm": 80.0, "arm_max": 300.0,
                           "max_angular_velocity": 3.0}
    return m


def arm_window():
    """One move along the line x = 30 from (30, 0) to (30, 40), 0 → 100 mm/s → 0 at 1000 mm/s²: r goes from
    30 to 50 mm, θ from 0 to atan2(40, 30) = 0.927295218 rad."""
    return join([trapezoid_move([30, 0, 0, 0], [30, 40, 0, 0], 0.0, 100.0, 0.0, 1000.0, 0.0, 0)])


def test_polar_motor_rows_are_atan2_and_hypot_of_the_toolhead():
    fig = plots.plot_axes(arm_window(), polar_machine())
    t, x = xy(line_by_gid(fig, "pos_x"))
    _, y = xy(line_by_gid(fig, "pos_y"))
    _, bed = xy(line_by_gid(fig, "pos_bed"))
    _, arm = xy(line_by_gid(fig, "pos_arm"))
    # the hand-worked ends: (30, 0) → θ = 0, r = 30; (30, 40) → θ = atan2(4, 3) = 0.9272952180016122, r = 50
    assert (bed[0], arm[0]) == (0.0, 30.0)
    assert bed[-1] == pytest.approx(0.9272952180016122, abs=1e-12) and arm[-1] == pytest.approx(50.0, abs=1e-12)
    # and at every plotted point
    np.testing.assert_allclose(bed, np.arctan2(y, x), atol=1e-12)
    np.testing.assert_allclose(arm, np.hypot(x, y), atol=1e-12)
    # velocities: along x = 30 at speed y', θ' = 30·y'/r² rad/s and r' = y·y'/r mm/s
    _, vy = xy(line_by_gid(fig, "vel_y"))
    _, vbed = xy(line_by_gid(fig, "vel_bed"))
    _, varm = xy(line_by_gid(fig, "vel_arm"))
    r2 = x * x + y * y
    np.testing.assert_allclose(vbed, 30.0 * vy / r2, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(varm, y * vy / np.sqrt(r2), rtol=1e-7, atol=1e-9)
    # at cruise halfway (y = 20, y' = 100): θ' = 3000/1300 = 2.3077 rad/s, r' = 2000/36.056 = 55.470 mm/s
    k = np.argmin(np.abs(y - 20.0))
    assert abs(y[k] - 20.0) < 1.0 and vy[k] == pytest.approx(100.0)
    assert vbed[k] == pytest.approx(3000.0 / r2[k], rel=1e-7)
    # the Z motor is the Z axis itself (no row of its own); the rows say their units
    names = {ln.get_gid() for ax in fig.axes for ln in ax.get_lines()}
    assert "pos_z motor" not in names and "pos_z" in names
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "bed (rad)" in labels and "arm (units/s)" in labels


def test_polar_bed_angle_is_followed_across_the_half_turn():
    """A move from (−30, 10) to (−30, −10) crosses θ = ±π: the bed turns on through π (as the step engine
    follows it), it does not jump back by 2π, and its speed stays the geometric one."""
    win = join([trapezoid_move([-30, 10, 0, 0], [-30, -10, 0, 0], 0.0, 50.0, 0.0, 1000.0, 0.0, 0)])
    fig = plots.plot_axes(win, polar_machine())
    _, x = xy(line_by_gid(fig, "pos_x"))
    _, y = xy(line_by_gid(fig, "pos_y"))
    _, bed = xy(line_by_gid(fig, "pos_bed"))
    _, vy = xy(line_by_gid(fig, "vel_y"))
    _, vbed = xy(line_by_gid(fig, "vel_bed"))
    assert bed[0] == pytest.approx(math.atan2(10, -30)) and bed[-1] == pytest.approx(2 * math.pi + math.atan2(-10, -30))
    assert np.all(np.diff(bed) >= 0)
    np.testing.assert_allclose(np.mod(bed, 2 * math.pi), np.mod(np.arctan2(y, x), 2 * math.pi), atol=1e-12)
    np.testing.assert_allclose(vbed, -30.0 * vy / (x * x + y * y), rtol=1e-7, atol=1e-9)


def test_polar_bed_speed_at_the_centre_is_a_gap_not_a_spike():
    """A straight line through the centre at 100 mm/s, (−30, −40) → (0, 0) → (30, 40): the bed does not turn
    (θ' = 0 off the centre, the line is radial); at the centre the angle jumps by π and has no derivative, so
    the velocity there is a gap (NaN), not that jump divided by the difference's time step (~1e5 rad/s)."""
    win = join([trapezoid_move([-30, -40, 0, 0], [0, 0, 0, 0], 0.0, 100.0, 100.0, 1000.0, 0.0, 0),
                trapezoid_move([0, 0, 0, 0], [30, 40, 0, 0], 100.0, 100.0, 0.0, 1000.0, 0.55, 1)])
    fig = plots.plot_axes(win, polar_machine())
    _, x = xy(line_by_gid(fig, "pos_x"))
    _, y = xy(line_by_gid(fig, "pos_y"))
    _, vbed = xy(line_by_gid(fig, "vel_bed"))
    _, varm = xy(line_by_gid(fig, "vel_arm"))
    _, vx = xy(line_by_gid(fig, "vel_x"))
    r = np.hypot(x, y)
    centre = r == 0.0
    assert centre.sum() >= 2 and np.all(np.isnan(vbed[centre]))       # both sides of the boundary there
    far = r > 0.01                                                      # beyond the differences' reach
    assert np.all(np.isfinite(vbed[far])) and np.max(np.abs(vbed[far])) < 1e-6
    near = ~centre & ~far
    assert np.all(np.isnan(vbed[near]) | (np.abs(vbed[near]) < 1e-6))
    # the arm: r' = ±|v| = ±x'·5/3 (in towards the centre, then out)
    np.testing.assert_allclose(varm[far], np.sign(x[far]) * vx[far] * 5.0 / 3.0, rtol=1e-7, atol=1e-9)


def test_shaped_polar_machine_commanded_motor_is_the_geometry():
    """With input shaping the motors get commanded and driven rows (as a delta's towers): the commanded bed
    angle and arm are atan2 / hypot of the planned path; the driven ones are of the shaped path, whose X stays
    30 mm (a constant shaped is that constant): r·cos θ = 30 at every point while θ lags the commanded one."""
    fig = plots.plot_axes(arm_window(), polar_machine(shaper_freq_x=40.0, shaper_freq_y=40.0))
    _, x = xy(line_by_gid(fig, "pos_x"))
    _, y = xy(line_by_gid(fig, "pos_y"))
    _, cmd = xy(line_by_gid(fig, "cmd_bed"))
    _, cmd_arm = xy(line_by_gid(fig, "cmd_arm"))
    _, drv = xy(line_by_gid(fig, "motor_bed"))
    _, drv_arm = xy(line_by_gid(fig, "motor_arm"))
    np.testing.assert_allclose(cmd, np.arctan2(y, x), atol=1e-12)
    np.testing.assert_allclose(cmd_arm, np.hypot(x, y), atol=1e-12)
    np.testing.assert_allclose(drv_arm * np.cos(drv), 30.0, atol=1e-9)
    assert np.max(np.abs(drv - cmd)) > 1e-4          # shaped: not the commanded angle
    # the shaper spreads each change over its pulses (mzv at 40 Hz: within ~20 ms): the driven angle stays
    # within what the bed turns in that time (θ' ≤ 100 mm/s / 30 mm = 3.3 rad/s) of the commanded one
    assert np.all(np.abs(drv - cmd) <= 3.4 * 0.020)
    assert any(ax.get_ylabel() == "motor bed (rad)" for ax in fig.axes)


def test_plot_command_on_klippers_polar_config(tmp_path):
    """``gcodeplan plot --what axes --machine polar.cfg``: the picture has the bed and arm rows."""
    from gcodeplan.cli import main

    cfg = shared_path("reference", "klipper", "kinematics", "polar.cfg")
    prog = tmp_path / "p.gcode"
    prog.write_text("G28\nG1 X30 Y30 F6000\nG1 X60 Y30\nG1 X60 Y60\n")
    out = tmp_path / "axes.svg"
    assert main(["plot", str(prog), "--what", "axes", "--machine", str(cfg), "-o", str(out)]) == 0
    svg = out.read_text()
    for gid in ("pos_bed", "vel_bed", "pos_arm", "vel_arm"):
        assert f'id="{gid}' in svg, gid
