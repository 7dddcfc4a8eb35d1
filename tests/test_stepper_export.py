"""Writing steps: streamed .npz/.csv, atomic outputs, the ``steps`` command end to end."""
from __future__ import annotations

import errno
import os

import numpy as np
import pytest

from gcodeplan.errors import GcodeplanError
from gcodeplan.stepper.compress import decompress_runs
from gcodeplan.stepper.export import CsvStepWriter, NpzStreamWriter, load_npz


def _leftovers(directory):
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def test_npz_stream_round_trip(tmp_path):
    out = tmp_path / "s.npz"
    rng = np.random.default_rng(3)
    chunks = [rng.random(n) for n in (5, 0, 1000, 17)]
    with NpzStreamWriter(out) as w:
        w.declare("x", np.float64)
        w.declare("x_dir", np.int8)
        w.declare("empty", np.float64)
        for c in chunks:
            w.append("x", c)
            w.append("x_dir", np.where(c > 0.5, 1, -1))
        w.put("steppers", np.array(["x"]))
    got = load_npz(out)
    assert np.array_equal(got["x"], np.concatenate(chunks))
    assert got["x_dir"].dtype == np.int8 and len(got["x_dir"]) == 1022
    assert got["empty"].shape == (0,) and list(got["steppers"]) == ["x"]
    assert _leftovers(tmp_path) == []


def test_npz_abort_on_error_leaves_nothing(tmp_path):
    out = tmp_path / "s.npz"
    out.write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        with NpzStreamWriter(out) as w:
            w.declare("x", np.float64)
            w.append("x", np.ones(10))
            raise KeyboardInterrupt
    assert out.read_bytes() == b"old"          # the previous file is untouched
    assert _leftovers(tmp_path) == []


def test_full_disk_is_a_clear_error(tmp_path, monkeypatch):
    import gcodeplan.stepper.export as export

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(export.shutil, "copyfileobj", full)
    out = tmp_path / "s.npz"
    w = NpzStreamWriter(out)
    w.declare("x", np.float64)
    w.append("x", np.ones(3))
    with pytest.raises(GcodeplanError, match="No space left on device"):
        w.commit()
    assert not out.exists() and _leftovers(tmp_path) == []


def test_missing_directory_is_a_clear_error(tmp_path):
    with pytest.raises(GcodeplanError, match="does not exist"):
        NpzStreamWriter(tmp_path / "nope" / "s.npz")


def test_csv_writer(tmp_path):
    w = CsvStepWriter(tmp_path / "csv", ["x", "y"])
    w.append(0, np.array([0.25, 0.5]), np.array([1, -1], np.int8))
    w.append(0, np.array([1.0]), np.array([1], np.int8))
    w.commit()
    assert (tmp_path / "csv" / "x.csv").read_text().splitlines() == [
        "time_s,dir", "0.2500000000,1", "0.5000000000,-1", "1.0000000000,1"]
    assert (tmp_path / "csv" / "y.csv").read_text() == "time_s,dir\n"
    assert _leftovers(tmp_path / "csv") == []


# ------------------------------------------------------------------------------ the command


GCODE = "G90\nG1 X10 Y5 F3000\nG1 X0 Y0\nG1 X3.3 Y-2.2\n"


@pytest.fixture
def gfile(tmp_path):
    p = tmp_path / "part.gcode"
    p.write_text(GCODE)
    return p


def _main(argv):
    from gcodeplan.cli import main

    return main([str(a) for a in argv])


def test_steps_command_writes_everything(gfile, tmp_path, capsys):
    out = tmp_path / "steps.npz"
    rc = _main(["steps", gfile, "--machine", "klipper", "-o", out, "--csv", tmp_path / "csv", "--compress",
                "--max-error", "10e-6"])
    assert rc == 0
    z = load_npz(out)
    names = list(z["steppers"])
    assert len(names) == 4 and str(z["kinematics"]) in ("cartesian", "corexy")
    spm = dict(zip(names, z["steps_per_mm"]))
    text = capsys.readouterr().out
    for name in names:
        t, d = z[name], z[name + "_dir"]
        assert d.dtype == np.int8 and t.dtype == np.float64 and np.all(np.diff(t) >= 0)
        assert f"{name}: " in text
        rows = (tmp_path / "csv" / f"{name}.csv").read_text().splitlines()
        assert len(rows) == len(t) + 1
        clocks, rd = decompress_runs(z[name + "_runs"])
        assert np.array_equal(rd, d)
        assert np.max(np.abs(clocks / float(z["clock_hz"]) - t), initial=0) <= 10e-6 + 1e-8
    # net steps of the first stepper: the head ends at X = 3.3, Y = −2.2
    first = names[0]
    net = int(np.sum(z[first + "_dir"], dtype=np.int64))
    pos = 3.3 + (-2.2 if str(z["kinematics"]) == "corexy" else 0.0)
    assert net == round(pos * spm[first])


def test_unwritable_output_is_exit_2(gfile, tmp_path, capsys):
    rc = _main(["steps", gfile, "--machine", "klipper", "-o", tmp_path / "missing" / "s.npz"])
    assert rc == 2
    assert "does not exist" in capsys.readouterr().err


def test_interrupt_leaves_no_partial_file(gfile, tmp_path, monkeypatch):
    from gcodeplan.stepper import generate

    def boom(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(generate.StepGenerator, "feed", boom)
    out = tmp_path / "s.npz"
    rc = _main(["steps", gfile, "--machine", "klipper", "-o", out, "--csv", tmp_path / "csv"])
    assert rc == 130
    assert not out.exists() and _leftovers(tmp_path) == []
    assert not (tmp_path / "csv").exists()          # the directory it made is removed again


def test_bad_option_values_are_exit_2(gfile, tmp_path, capsys):
    rc = _main(["steps", gfile, "-o", tmp_path / "s.npz", "--max-error", "-1"])
    assert rc == 2 and "--max-error" in capsys.readouterr().err
    rc = _main(["steps", tmp_path / "nope.gcode", "-o", tmp_path / "s.npz"])
    assert rc == 2 and "nope.gcode" in capsys.readouterr().err


def test_step_rate_warning(gfile, tmp_path, capsys):
    rc = _main(["steps", gfile, "--machine", "klipper", "-o", tmp_path / "s.npz", "--max-step-rate", "1000", "-q"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "warning" in err and "above the maximum step rate 1,000" in err
