"""`gcodeplan profile`: printed phases, exit codes, and the plot's data."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from gcodeplan import cli, profiles
from gcodeplan.commands import profile as profile_cmd


def test_prints_phases_and_total_time(capsys):
    rc = cli.main(["profile", "--distance", "10", "--v-max", "100", "--a-max", "3000", "--j-max", "1e5"])
    out = capsys.readouterr().out
    assert rc == 0
    # T = h/V + V/A + A/J = 0.1 + 0.0333.. + 0.03
    assert "total time: 0.163333333 s" in out
    rows = [line.split() for line in out.splitlines() if line.strip()[:1].isdigit()]
    assert len(rows) == 7
    assert [float(r[3]) for r in rows] == [1e5, 0.0, -1e5, 0.0, -1e5, 0.0, 1e5]
    assert float(rows[3][4]) == pytest.approx(100.0)            # velocity at the end of the cruise
    assert float(rows[4][1]) == pytest.approx(0.1)              # phase 5 starts at 0.1 s


def test_trapezoid_with_end_speeds(capsys):
    rc = cli.main(["profile", "--distance", "16", "--v-max", "4", "--a-max", "20", "--v-end", "2"])
    out = capsys.readouterr().out
    assert rc == 0 and "accel mm/s²" in out
    assert f"total time: {profiles.trapezoid(16, 4, 20, v_end=2).duration:.9f} s" in out


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--distance", "10", "--v-max", "100", "--a-max", "-5"], "--a-max must be > 0"),
        (["--distance", "10", "--v-max", "100", "--a-max", "100", "--v-start", "200"], "--v-start"),
        (["--distance", "0.001", "--v-max", "100", "--a-max", "3000", "--j-max", "1e5", "--v-start", "50"],
         "cannot go from v_start = 50"),
        (["--distance", "nan", "--v-max", "100", "--a-max", "3000"], "--distance"),
        (["--distance", "1", "--v-max", "100", "--a-max", "3000", "--j-max", "1e5", "--decel", "5"], "--decel"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(argv, needle, capsys):
    rc = cli.main(["profile", *argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert needle in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_plot_is_written_and_its_lines_are_the_samples(tmp_path, capsys):
    out = tmp_path / "p.png"
    rc = cli.main(["profile", "--distance", "5", "--v-max", "80", "--a-max", "2000", "--j-max", "5e4",
                   "--v-start", "10", "--plot", str(out)])
    assert rc == 0 and out.stat().st_size > 1000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = profiles.scurve(5, 80, 2000, 5e4, v_start=10)
    fig = profile_cmd.plot_profile(p, str(tmp_path / "again.png"))
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["position (mm)", "velocity (mm/s)", "acceleration (mm/s²)", "jerk (mm/s³)"]
    assert fig.axes[-1].get_xlabel() == "time (s)"
    for k, ax in enumerate(fig.axes):
        (line,) = ax.get_lines()
        t = line.get_xdata()
        assert t[0] == 0.0 and t[-1] == pytest.approx(p.duration)
        np.testing.assert_array_equal(line.get_ydata(), p.sample(t)[k])


def test_unwritable_plot_path_is_a_clean_error(capsys):
    rc = cli.main(["profile", "--distance", "5", "--v-max", "80", "--a-max", "2000",
                   "--plot", "/nonexistent-dir/x.png"])
    assert rc == 2 and "cannot write plot" in capsys.readouterr().err


def test_add_arguments_defaults():
    parser = argparse.ArgumentParser()
    profile_cmd.add_arguments(parser)
    args = parser.parse_args(["--distance", "1", "--v-max", "2", "--a-max", "3"])
    assert (args.v_start, args.v_end, args.j_max, args.plot) == (0.0, 0.0, None, None)
