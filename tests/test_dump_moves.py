"""gcodeplan dump-moves: one CSV row per planned row, equal to the plan (gp.plan) to the printed digits."""
from __future__ import annotations

import csv
import os

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.cli import main
from gcodeplan.commands.dump_moves import COLUMNS
from gcodeplan.schema import KIND_NAMES, LIMIT_NAMES

from conftest import shared_path

TEXT = """M83
G28
;TYPE:Skirt
G1 X10 Y10 F6000
EXCLUDE_OBJECT_START NAME="part, one"
;TYPE:External perimeter
G1 X30 Y10 E1 F1200
G1 X30 Y30 E1
G4 P250
EXCLUDE_OBJECT_END
G1 E-0.8 F2100
"""


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_rows_equal_the_plan(tmp_path):
    src = tmp_path / "a.gcode"
    src.write_text(TEXT)
    out = tmp_path / "moves.csv"
    assert main(["dump-moves", str(src), "-o", str(out), "-q"]) == 0
    rows = _read(out)
    with open(out) as f:
        assert f.readline().strip().split(",") == [c for c, _ in COLUMNS]
    p = gp.plan(str(src))
    assert len(rows) == len(p.moves)
    for r, m, q in zip(rows, p.moves, p.plan):
        assert int(r["line"]) == m["line"] and r["kind"] == KIND_NAMES[m["kind"]]
        for col, f in (("x0", "x0"), ("y1", "y1"), ("e1", "e1"), ("length_mm", "move_d")):
            assert float(r[col]) == pytest.approx(m[f], abs=1e-5)
        for col in ("start_v", "cruise_v", "end_v"):
            assert float(r[col]) == pytest.approx(q[col], abs=1e-4)
        for col in ("accel_t", "cruise_t", "decel_t", "t_start", "duration"):
            assert float(r[col]) == pytest.approx(q[col], abs=1e-7)
        assert r["limited_by"] == LIMIT_NAMES[q["limit"]]
        assert int(r["layer"]) == m["layer"]
    # names: the feature and the object (a comma in the name: quoted), empty outside
    assert [r["feature"] for r in rows] == ["", "skirt", "external perimeter", "external perimeter",
                                            "external perimeter", "external perimeter"]
    assert [r["object"] for r in rows] == ["", "", "part, one", "part, one", "part, one", ""]
    assert sum(float(r["duration"]) for r in rows) == pytest.approx(p.total_time_s, abs=1e-6)
    # phases add up to each motion row's duration
    for r in rows:
        if r["kind"] in ("travel", "print", "extrude_only"):
            assert float(r["accel_t"]) + float(r["cruise_t"]) + float(r["decel_t"]) == \
                pytest.approx(float(r["duration"]), abs=3e-7)


def test_error_leaves_no_output(tmp_path, capsys):
    src = tmp_path / "a.gcode"
    src.write_text(TEXT + "G1 X1 X2\n")
    out = tmp_path / "moves.csv"
    assert main(["dump-moves", str(src), "-o", str(out), "-q"]) == 2
    assert "a.gcode:12" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["a.gcode"]


def test_exclude_object_drops_its_rows(tmp_path):
    src = tmp_path / "a.gcode"
    src.write_text(TEXT)
    out = tmp_path / "moves.csv"
    assert main(["dump-moves", str(src), "-o", str(out), "-q", "--exclude-object", "PART, ONE"]) == 0
    rows = _read(out)
    assert "part, one" not in {r["object"] for r in rows if r["kind"] != "dwell"}


@pytest.mark.slow
def test_multi_object_plate_durations_sum_to_the_total(tmp_path):
    src = shared_path("gcode", "prusaslicer25_multi_object_plate_relE.gcode")
    out = tmp_path / "moves.csv"
    assert main(["dump-moves", str(src), "-o", str(out), "-q"]) == 0
    est = gp.estimate(str(src))
    dur = 0.0
    t_prev = -1.0
    objects = set()
    n = 0
    with open(out, newline="") as f:
        for r in csv.DictReader(f):
            dur += float(r["duration"])
            t = float(r["t_start"])
            assert t >= t_prev - 1e-7
            t_prev = t
            objects.add(r["object"])
            n += 1
    assert n == est.time.moves_planned
    # each duration is printed to 1e-7 s: the sum is within n·5e-8 of the total; the last row ends at it
    assert abs(dur - est.total_time_s) <= n * 5e-8
    assert t + float(r["duration"]) == pytest.approx(est.total_time_s, abs=2e-7)
    assert objects == set(est.objects) | {""}
    assert np.isfinite(dur)
