"""Per-object times, --exclude-object as Klipper's exclude_object runs it, flow, and the machine's [time].

Truths: the same print with the object's lines removed by hand (relative E), or removed with the extruder
position set by hand where Klipper carries it over (absolute E, G92 E); closed-form flow of one move; the
sums of every breakdown.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.cli import main
from gcodeplan.errors import GcodeError
from gcodeplan.gcode import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import MOVE_DTYPE

from conftest import shared_path

LABELS = """M83
G1 X0 Y0 F6000
EXCLUDE_OBJECT_DEFINE NAME=part_a
EXCLUDE_OBJECT_START NAME=part_a
G1 X10 E1
G2 X20 Y0 I5 J0 E1
EXCLUDE_OBJECT_END NAME=part_a
M486 S0
M486 Acube one
G1 X20 Y10 E1
M486 S-1
; printing object foo id:0 copy 0
G1 X30 E1
; stop printing object foo id:0 copy 0
;MESH:bar.stl
G1 X40 E1
;MESH:NONMESH
G1 X50 E1
"""


def _write(tmp_path, text, name="t.gcode"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def _same(a, b):
    return all(np.array_equal(a[f], b[f], equal_nan=a[f].dtype.kind == "f") for f in MOVE_DTYPE.names)


@pytest.mark.parametrize("flavor", ["klipper", "marlin"])
def test_every_label_kind_tags_the_rows_and_both_parsers_agree(tmp_path, flavor):
    path = _write(tmp_path, LABELS)
    a, ra = read_moves(path, Machine(flavor=flavor))
    b, rb = read_moves(path, Machine(flavor=flavor), force_python=True)
    assert _same(a, b)
    names = ra.interp.objects.names
    assert names == rb.interp.objects.names == ["part_a", "cube one", "foo id:0 copy 0", "bar.stl"]
    tagged = [names[i] if i >= 0 else None for i in a["object"]]
    # part_a: its line and the chords of its arc; then one row each
    assert tagged[-4:] == ["cube one", "foo id:0 copy 0", "bar.stl", None]
    assert set(tagged[:-4]) == {"part_a"} and len(tagged) > 6


def test_objects_sum_to_the_total_and_show_in_json_and_text(tmp_path, capsys):
    path = _write(tmp_path, "G28\n" + LABELS)
    assert main(["estimate", "--json", "-q", path]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d["objects"]) == {"part_a", "cube one", "foo id:0 copy 0", "bar.stl"}
    assert sum(d["objects"].values()) + d["outside_objects_s"] == pytest.approx(d["total_time_s"], rel=1e-12)
    assert all(v > 0 for v in d["objects"].values()) and d["outside_objects_s"] > 0
    assert main(["estimate", "-q", path]) == 0
    text = capsys.readouterr().out
    assert "time per object:" in text and "(outside any object)" in text


def _without(text: str, start: str, end: str, replace: str = "") -> str:
    a = text.index(start)
    b = text.index(end, a) + len(end)
    return text[:a] + replace + text[b:]


REL = """M83
G1 X5 Y5 F6000
EXCLUDE_OBJECT_START NAME=A
G1 E-0.8 F2100
G1 X10 Y10 F6000
G1 E0.8 F2100
G1 X20 Y10 E1 F1200
G1 X20 Y20 E1
EXCLUDE_OBJECT_END NAME=A
EXCLUDE_OBJECT_START NAME=B
G1 E-0.8 F2100
G1 Z0.6 F600
G1 X60 Y60 F6000
G1 Z0.2 F600
G1 E0.8 F2100
G1 X80 Y60 E1.5 F1200
G1 X80 Y80 E1.5
EXCLUDE_OBJECT_END NAME=B
EXCLUDE_OBJECT_START NAME=C
G1 E-0.8 F2100
G1 Z0.6 F600
G1 X30 Y40 F6000
G1 Z0.2 F600
G1 E0.8 F2100
G1 X40 Y40 E1 F1200
G1 X40 Y50 E1
EXCLUDE_OBJECT_END NAME=C
"""


def test_exclude_with_relative_e_equals_the_lines_removed(tmp_path):
    full = _write(tmp_path, REL, "full.gcode")
    cut = _write(tmp_path, _without(REL, "EXCLUDE_OBJECT_START NAME=B", "EXCLUDE_OBJECT_END NAME=B\n"), "cut.gcode")
    ex = gp.plan(full, exclude_objects=["b"])          # names are case-insensitive, as in Klipper
    ref = gp.plan(cut)
    # the moves Klipper runs: B's rows gone, C's first travel from where A ended, E as commanded
    for f in ("x0", "y0", "z0", "x1", "y1", "z1", "move_d", "kind", "accel", "feed_v"):
        assert np.allclose(ex.moves[f], ref.moves[f], rtol=0, atol=1e-12), f
    assert np.allclose(ex.moves["e1"] - ex.moves["e0"], ref.moves["e1"] - ref.moves["e0"], rtol=0, atol=1e-12)
    assert ex.total_time_s == ref.total_time_s
    assert ex.total_time_s < gp.estimate(full).total_time_s


def _absolute(text: str) -> str:
    """REL with absolute E values (cumulative), the way an M82 slicer writes it."""
    out, e = [], 0.0
    for ln in text.splitlines():
        if " E" in ln and ln.startswith("G1"):
            words = ln.split()
            for i, w in enumerate(words):
                if w.startswith("E"):
                    e = round(e + float(w[1:]), 5)
                    words[i] = f"E{e:.5f}"
            ln = " ".join(words)
        out.append(ln)
    return "\n".join(out).replace("M83", "M82\nG92 E0") + "\n"


def test_exclude_with_absolute_e_carries_the_extruder_position_over(tmp_path):
    text = _absolute(REL)
    full = _write(tmp_path, text, "full.gcode")
    # by hand: B's lines removed and the extruder told where B left it (what Klipper's E offset does)
    b_end = [ln for ln in text.split("EXCLUDE_OBJECT_END NAME=B")[0].splitlines() if " E" in ln][-1]
    e_after_b = float(b_end.split(" E")[1].split()[0])
    cut = _write(tmp_path, _without(text, "EXCLUDE_OBJECT_START NAME=B", "EXCLUDE_OBJECT_END NAME=B\n",
                                    f"G92 E{e_after_b:.5f}\n"), "cut.gcode")
    ex_est = gp.estimate(full, gp.load_machine(), exclude_objects=["B"])
    ref = gp.estimate(cut, gp.load_machine())
    assert ex_est.total_time_s == pytest.approx(ref.total_time_s, rel=1e-14)
    # without the carry-over C's first printing move would push B's 3.8 mm of filament too
    naive = gp.estimate(_write(tmp_path, _without(text, "EXCLUDE_OBJECT_START NAME=B",
                                                  "EXCLUDE_OBJECT_END NAME=B\n"), "naive.gcode"))
    assert naive.total_time_s != pytest.approx(ref.total_time_s, rel=1e-9)


def test_exclude_absolute_e_klipper_retraction_adjustment(tmp_path):
    """B ends retracted (0.8 mm below its highest E), A did not: Klipper's extruder_adj (max_excluded −
    last_excluded − (max_extruded − last_extruded) = 0.8) is added to the E offset on the first move after
    B, so the travel to C retracts the real extruder by 0.8 mm and C's unretract pushes it back: worked by
    hand through klippy/extras/exclude_object.py below."""
    text = """M82
G92 E0
G1 X5 Y5 F6000
EXCLUDE_OBJECT_START NAME=A
G1 X20 Y5 E2 F1200
EXCLUDE_OBJECT_END NAME=A
EXCLUDE_OBJECT_START NAME=B
G1 X60 Y5 F6000
G1 X80 Y5 E5 F1200
G1 E4.2 F2100
EXCLUDE_OBJECT_END NAME=B
EXCLUDE_OBJECT_START NAME=C
G1 X40 Y40 F6000
G1 E5 F2100
G1 X50 Y40 E6 F1200
EXCLUDE_OBJECT_END NAME=C
"""
    # skipped E: 5 − 2 − 0.8 = 2.2, plus adj 0.8: offset 3.0 from the travel to C on
    by_hand = """M82
G92 E0
G1 X5 Y5 F6000
G1 X20 Y5 E2 F1200
G1 X40 Y40 E1.2 F6000
G1 E2 F2100
G1 X50 Y40 E3 F1200
"""
    m = gp.load_machine()
    ex = gp.plan(_write(tmp_path, text, "full.gcode"), m, exclude_objects=["B"])
    ref = gp.plan(_write(tmp_path, by_hand, "hand.gcode"), m)
    for f in ("x0", "y0", "z0", "e0", "x1", "y1", "z1", "e1", "move_d", "kind", "accel", "feed_v"):
        assert np.allclose(ex.moves[f], ref.moves[f], rtol=0, atol=1e-12), f
    assert ex.total_time_s == pytest.approx(ref.total_time_s, rel=1e-14)


def test_unknown_exclude_name_is_an_error(tmp_path):
    path = _write(tmp_path, REL)
    with pytest.raises(GcodeError, match="no object named 'Z'.*objects: 'A', 'B', 'C'"):
        gp.estimate(path, exclude_objects=["Z"])


def test_exclude_object_command_in_the_file(tmp_path):
    text = REL.replace("EXCLUDE_OBJECT_START NAME=B", "EXCLUDE_OBJECT NAME=B\nEXCLUDE_OBJECT_START NAME=B")
    a = gp.estimate(_write(tmp_path, text, "a.gcode"))
    b = gp.estimate(_write(tmp_path, REL, "b.gcode"), exclude_objects=["B"])
    assert a.total_time_s == b.total_time_s


@pytest.mark.slow
def test_multi_object_plate_objects_sum_and_exclusion_equals_lines_removed(tmp_path):
    src = shared_path("gcode", "prusaslicer25_multi_object_plate_relE.gcode")
    est = gp.estimate(str(src))
    d = est.to_json()
    assert len(d["objects"]) == 4
    assert sum(d["objects"].values()) + d["outside_objects_s"] == pytest.approx(est.total_time_s, rel=1e-12)
    name = "cube20.stl id:0 copy 0"
    out, skip = [], False
    for ln in src.read_bytes().split(b"\n"):
        if ln.startswith(b"; printing object " + name.encode()):
            skip = True
            continue
        if ln.startswith(b"; stop printing object " + name.encode()):
            skip = False
            continue
        if not skip:
            out.append(ln)
    cut = tmp_path / "cut.gcode"
    cut.write_bytes(b"\n".join(out))
    ex = gp.estimate(str(src), exclude_objects=[name])
    assert ex.total_time_s == gp.estimate(str(cut)).total_time_s
    assert ex.to_json()["objects"][name] == 0.0


# ---------------------------------------------------------------------------- flow

def test_flow_of_one_move_closed_form(tmp_path):
    """10 mm at 10 mm/s pushing 1 mm of 1.75 mm filament, from rest to rest at 3000 mm/s²: the trapezoid
    lasts 10/10 + 10/3000 s; average = volume / that; peak = 10 mm/s · 0.1 · π·1.75²/4."""
    path = _write(tmp_path, "M83\nG1 X10 E1 F600\n")
    d = gp.estimate(path).to_json()
    area = math.pi * 1.75 ** 2 / 4
    f = d["flow"]["features"]["(untagged)"]
    assert f["peak_mm3_s"] == pytest.approx(area, rel=1e-12)
    assert f["average_mm3_s"] == pytest.approx(area / (1 + 1 / 300), rel=1e-12)
    assert d["flow"]["layers"][0]["peak_mm3_s"] == pytest.approx(area, rel=1e-12)


# ---------------------------------------------------------------------------- [time]

def test_time_the_gcode_does_not_show_appears_as_named_waits(tmp_path, capsys):
    machine = tmp_path / "m.toml"
    machine.write_text('base = "klipper"\n[time]\nmacros = { PRINT_START = 240, PRINT_END = 30, G29 = 90 }\n'
                       "tool_change_time = 12\nfilament_change_time = 100\nstart_time = 7\n")
    body = "PRINT_START BED=60\nG29\nT0\nG1 X10 F600\nT1\nG1 X20\nT1\nM600\nG1 X30\nPRINT_END\n"
    path = _write(tmp_path, body)
    plain = gp.estimate(path).total_time_s
    est = gp.estimate(path, gp.load_machine(str(machine)))
    d = est.to_json()
    # T0 keeps the tool the printer starts with, the second T1 too: one tool change
    assert d["waits_by_name_s"] == {"start": 7.0, "PRINT_START": 240.0, "G29": 90.0, "tool_change": 12.0,
                                    "M600": 100.0, "PRINT_END": 30.0}
    assert d["waits_s"] == pytest.approx(479.0, abs=1e-9)
    assert est.total_time_s == pytest.approx(plain + 479.0, abs=1e-9)
    assert "PRINT_START" not in d["unknown_commands"]
    assert main(["estimate", "-q", "--machine", str(machine), path]) == 0
    assert "waits by name:" in capsys.readouterr().out


def test_start_time_row_comes_first_and_scanner_path_agrees(tmp_path):
    m = Machine(flavor="klipper", start_time=5.0)
    path = _write(tmp_path, "G1 X10 F600\nG1 X20\n")
    a, _ = read_moves(path, m)
    b, _ = read_moves(path, m, force_python=True)
    assert _same(a, b)
    assert a["kind"][0] == 4 and a["dwell_t"][0] == 5.0 and a["line"][0] == 1
