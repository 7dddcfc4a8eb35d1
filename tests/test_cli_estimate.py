"""`gcodeplan estimate` end to end: the JSON contract, many files, exit codes, Klipper's totals."""
import json

import pytest

from gcodeplan.cli import main
from conftest import SAMPLES, shared_path

KLIPPER_SYNTHETIC_TOTALS = {  # ../shared/reference/klipper/README.md
    "a_long_x.gcode": 2.033333333,
    "b_square.gcode": 4.123583333,
    "c_circle200.gcode": 2.529837438,
    "d_slicer_like.gcode": 43.283454874,
}


def _json(capsys, *argv):
    assert main(["estimate", "--json", "--quiet", *argv]) == 0
    return json.loads(capsys.readouterr().out)


def test_json_has_the_published_keys_and_consistent_totals(capsys):
    d = _json(capsys, str(SAMPLES / "prusaslicer25_cube20_marlin2.gcode"))
    for key in ("total_time_s", "moves", "layers", "features", "waits_s", "layer_count", "travel_mm", "print_mm",
                "filament_mm", "unknown_commands", "naive_time_s"):
        assert key in d
    # the parts add up to the whole: per-layer and per-feature times each sum to the total
    before_first_layer = d["total_time_s"] - sum(L["time_s"] for L in d["layers"])
    assert 0 <= before_first_layer < 60  # only the start G-code (purge line) precedes ;LAYER_CHANGE
    assert sum(d["features"].values()) == pytest.approx(d["total_time_s"], rel=1e-9)
    kinds = d["print_time_s"] + d["travel_time_s"] + d["extrude_only_time_s"] + d["dwell_s"] + d["waits_s"]
    assert kinds == pytest.approx(d["total_time_s"], rel=1e-9)
    assert d["accelerating_s"] + d["cruising_s"] + d["decelerating_s"] == pytest.approx(
        d["total_time_s"] - d["dwell_s"] - d["waits_s"], rel=1e-9)
    # PrusaSlicer writes 99 ;LAYER_CHANGE blocks for a 20 mm cube at 0.2 mm layers
    assert d["layer_count"] == len(d["layers"]) == 99
    # Klipper's own planned total for this file (times.json), with the default (klipper) machine
    assert d["total_time_s"] == pytest.approx(1177.2300589989943, rel=1e-7)


@pytest.mark.parametrize("name,total", sorted(KLIPPER_SYNTHETIC_TOTALS.items()))
def test_default_machine_reproduces_klipper_totals(capsys, name, total):
    d = _json(capsys, str(SAMPLES / name))
    assert d["total_time_s"] == pytest.approx(total, abs=2e-9)


def test_klipper_config_option_gives_the_same_totals(capsys):
    cfg = shared_path("reference", "klipper", "cartesian_corpus.cfg")
    d = _json(capsys, "--klipper-config", str(cfg), str(SAMPLES / "b_square.gcode"))
    assert d["total_time_s"] == pytest.approx(4.123583333, abs=2e-9)


def test_many_files_in_parallel_print_one_row_each(capsys):
    files = [str(SAMPLES / n) for n in ("a_long_x.gcode", "b_square.gcode", "c_circle200.gcode")]
    assert main(["estimate", "--quiet", "--jobs", "2", *files]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 4 and all(any(f in line for line in out) for f in files)
    assert main(["estimate", "--quiet", "--json", "--jobs", "2", *files]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["total_time_s"] for r in rows] == pytest.approx([2.033333333, 4.123583333, 2.529837438], abs=2e-9)


def test_exact_stop_is_never_faster_than_klipper(capsys):
    f = str(SAMPLES / "c_circle200.gcode")
    fast = _json(capsys, f)["total_time_s"]
    slow = _json(capsys, "--policy", "exact-stop", f)["total_time_s"]
    assert slow > fast


@pytest.mark.parametrize("text,needle", [
    ("G1 X10\nG1 X1.2.3\n", ":2: "),
    ("G1 X10\nG1 Yabc\n", ":2: "),
    ("G1 X10\nG2 X0 Y10 I-5 J0\n", ":2: "),      # end not on the arc's circle
])
def test_bad_input_is_one_line_naming_file_and_line(tmp_path, capsys, text, needle):
    p = tmp_path / "bad.gcode"
    p.write_text(text)
    assert main(["estimate", "--quiet", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.gcode" + needle in err[0]


def test_one_bad_file_among_many_exits_2_but_reports_the_others(tmp_path, capsys):
    bad = tmp_path / "bad.gcode"
    bad.write_text("G1 Xnan\n")
    assert main(["estimate", "--quiet", str(SAMPLES / "a_long_x.gcode"), str(bad)]) == 2
    cap = capsys.readouterr()
    assert "a_long_x.gcode" in cap.out and "0:00:02" in cap.out
    assert "bad.gcode:1:" in cap.err


def test_missing_file_and_bad_options_exit_2(tmp_path, capsys):
    assert main(["estimate", str(tmp_path / "nope.gcode")]) == 2
    assert main(["estimate", "--jobs", "0", str(SAMPLES / "a_long_x.gcode")]) == 2
    assert main(["estimate", "--jerk", "-1", str(SAMPLES / "a_long_x.gcode")]) == 2
    # policies are a registry (gcodeplan.register_policy), so an unknown one is refused by name, exit 2
    assert main(["estimate", "--policy", "nonsense", str(SAMPLES / "a_long_x.gcode")]) == 2
    assert "unknown policy 'nonsense'" in capsys.readouterr().err


def test_over_extrusion_stops_like_klipper_but_tiny_amounts_pass(tmp_path, capsys):
    # klipper preset: max_extrude_cross_section 50 mm² -> 20.79 mm of filament per mm of path
    p = tmp_path / "over.gcode"
    p.write_text("G1 X10 F600\nG1 X11 E100\n")          # 100 mm over 1 mm: 240.5 mm²
    assert main(["estimate", "--quiet", str(p)]) == 2
    assert "over.gcode:2: move exceeds maximum extrusion (240.528 mm² vs 50.000 mm²)" in capsys.readouterr().err
    p.write_text("G1 X10 F600\nG1 X10.01 E5\n")         # 500 mm²-worth, but 5 mm < 0.4·20.79: allowed
    assert main(["estimate", "--quiet", str(p)]) == 0
    p.write_text("G1 X10 F600\nG1 X11 E100\n")
    assert main(["estimate", "--quiet", "--machine", "marlin", str(p)]) == 0   # Marlin has no such check


def test_the_readers_warnings_are_in_the_text_not_only_in_json(tmp_path, capsys):
    """A probe move timed to its target is a named warning: the plain `estimate` text shows it with its line,
    once (the JSON lists the same)."""
    p = tmp_path / "probe.ngc"
    p.write_text("G21 G90\nG0 X0 Y0 Z5\nG38.2 Z-5 F100\nM2\n")
    assert main(["estimate", "--machine", "grbl", str(p)]) == 0
    out = capsys.readouterr().out
    hits = [ln for ln in out.splitlines() if "probe moves are timed to their target" in ln]
    assert len(hits) == 1 and hits[0].startswith("  warning: ") and "probe.ngc:3:" in hits[0]
    assert main(["estimate", "--json", "--machine", "grbl", str(p)]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert any("probe moves are timed to their target" in w for w in warnings)
