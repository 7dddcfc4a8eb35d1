"""Every corpus file parses, and agrees with an independent line-by-line reference parser, with the
slicer's own layer counts and with Klipper's move counts (reference/klipper/times.json)."""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from conftest import SAMPLES, shared_path
from gcodeplan.gcode import GcodeReader, read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, KIND_WAIT
from conftest import same_rows

FDM_SMALL = ["prusaslicer25_cube20_marlin2.gcode", "cura413_ender3_cylinder30.gcode"]
FDM_BIG = ["prusaslicer25_twisted_vase_spiral.gcode", "prusaslicer25_multi_object_plate_relE.gcode",
           "prusaslicer25_plate150_gyroid_big.gcode"]
CNC = ["linuxcnc_stellabee1.ngc", "linuxcnc_plasmatest.ngc", "linuxcnc_arcspiral.ngc"]


def reference_fdm(path) -> tuple[int, int, float]:
    """A deliberately plain parser for slicer output: (moves, extrude-only moves, net E).

    Handles G0/G1, G90/G91, M82/M83, G92 and G28 (to 0); E relative under G91 or M83. Lines with an
    unexpanded ``{placeholder}`` are dropped (as Klipper's reference run did).
    """
    pos = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    e_log = 0.0
    abs_xyz, abs_e = True, True
    moves = e_only = 0
    net_e = 0.0
    with open(path, encoding="utf-8", errors="replace") as fh:
        for raw in fh:
            code = raw.split(";", 1)[0].strip()
            if not code or "{" in code:
                continue
            parts = code.upper().split()
            cmd, args = parts[0], {p[0]: float(p[1:]) for p in parts[1:] if len(p) > 1}
            if cmd in ("G0", "G1"):
                new = dict(pos)
                for k in "XYZ":
                    if k in args:
                        new[k] = args[k] if abs_xyz else pos[k] + args[k]
                de = 0.0
                if "E" in args:
                    if abs_xyz and abs_e:
                        de, e_log = args["E"] - e_log, args["E"]
                    else:
                        de = args["E"]
                moved = any(new[k] != pos[k] for k in "XYZ")
                if moved or de != 0.0:
                    moves += 1
                    e_only += not moved
                net_e += de
                pos = new
            elif cmd == "G90":
                abs_xyz = True
            elif cmd == "G91":
                abs_xyz = False
            elif cmd == "M82":
                abs_e = True
            elif cmd == "M83":
                abs_e = False
            elif cmd == "G92":
                if "E" in args:
                    e_log = args["E"]
            elif cmd == "G28":
                pos = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    return moves, e_only, net_e


def _check_fdm(name: str) -> None:
    path = shared_path("gcode", name)
    times = json.loads(shared_path("reference", "klipper", "times.json").read_text())[name]
    r = GcodeReader(str(path), Machine(flavor="klipper"))
    prev_end = None
    for b in r.batches():
        assert len(b) <= r.batch_moves
        # continuity: every row starts where the previous ended (a physical invariant of a toolpath)
        starts = np.stack([b["x0"], b["y0"], b["z0"], b["e0"]], 1)
        ends = np.stack([b["x1"], b["y1"], b["z1"], b["e1"]], 1)
        assert np.array_equal(starts[1:], ends[:-1])
        if prev_end is not None:
            assert np.array_equal(starts[0], prev_end)
        prev_end = ends[-1]
        assert np.all(np.diff(b["line"]) >= 0)
    s = r.summary
    moves, e_only, net_e = reference_fdm(path)
    assert s.moves == moves and s.moves_by_kind["extrude_only"] == e_only
    assert s.filament_mm == pytest.approx(net_e, rel=1e-9)
    assert s.moves == times["moves"] and s.moves_by_kind["extrude_only"] == times["moves_extrude_only"]
    data = path.read_bytes()
    if name.startswith("prusaslicer"):
        assert s.layer_count == data.count(b"\n;LAYER_CHANGE")
        assert s.slicer_estimate_s == times["slicer_estimate_s"]
        assert all(math.isfinite(z) for z in r.layer_z)
    else:
        assert s.layer_count == s.header_layer_count == int(re.search(rb";LAYER_COUNT:(\d+)", data).group(1))
        assert s.skipped_lines == 1      # G1 X0 Y{machine_depth}
    assert s.unknown_commands == {}
    assert s.lines == data.count(b"\n") + (not data.endswith(b"\n"))


@pytest.mark.parametrize("name", FDM_SMALL)
def test_fdm_corpus_small(name):
    _check_fdm(name)


@pytest.mark.slow
@pytest.mark.parametrize("name", FDM_BIG)
def test_fdm_corpus_big(name):
    _check_fdm(name)


def test_klipper_m204_count_and_limits_on_the_cube():
    path = shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode")
    times = json.loads(shared_path("reference", "klipper", "times.json").read_text())
    ref = times["prusaslicer25_cube20_marlin2.gcode"]["kept_but_ignored_by_klipper"]
    m, r = read_moves(str(path), Machine(flavor="klipper", max_accel=3000))
    ign = r.summary.ignored_commands
    assert ign["M204 without S or P+T"] == next(v for k, v in ref.items() if k.startswith("M204"))
    assert ign["M201"] == ref["M201"] and ign["M203"] == ref["M203"] and ign["M205"] == ref["M205"]
    # Klipper plans every PrusaSlicer move at min(P1250, T1500) once the header's M204 has run
    body = m[(m["line"] > 20) & (m["kind"] <= KIND_EXTRUDE_ONLY)]
    assert np.all(body["accel"] == 1250.0)


@pytest.mark.parametrize("name", ["linuxcnc_plasmatest.ngc", "linuxcnc_arcspiral.ngc"])
def test_cnc_corpus_small(name):
    _check_cnc(name)


@pytest.mark.slow
def test_cnc_corpus_stellabee():
    _check_cnc("linuxcnc_stellabee1.ngc")


def _check_cnc(name):
    path = shared_path("gcode", name)
    m, r = read_moves(str(path), Machine(flavor="linuxcnc"))
    s = r.summary
    assert s.unknown_commands == {} and s.warning_count == 0
    assert s.arcs > 0 and s.arc_chords >= s.arcs
    starts = np.stack([m["x0"], m["y0"], m["z0"]], 1)
    ends = np.stack([m["x1"], m["y1"], m["z1"]], 1)
    assert np.allclose(starts[1:], ends[:-1], atol=0, rtol=0)
    assert np.all(m["kind"][m["kind"] <= KIND_EXTRUDE_ONLY] == KIND_TRAVEL)   # no E on a mill
    text = path.read_text(errors="replace")
    if "G20" in text.upper():
        # inch files: every coordinate was ×25.4; the bounds of the file's own numbers, scaled, contain ours
        nums = [abs(float(v)) for v in re.findall(r"[XxYy]\s*(-?\d*\.?\d+)", text)]
        assert np.abs(m["x1"]).max() <= max(nums) * 25.4 * 1.5


def test_laser_corpus_m3_m5_g4_and_klipper_count():
    path = shared_path("gcode", "cncjs_jscut_tball_pocket_laser.gcode")
    times = json.loads(shared_path("reference", "klipper", "times.json").read_text())
    name = path.name
    m, r = read_moves(str(path), Machine(flavor="klipper"))
    assert r.summary.moves == times[name]["moves"]
    data = path.read_text()
    assert r.summary.moves_by_kind["dwell"] == len(re.findall(r"^G4 ", data, re.M))
    assert r.summary.spindle_commands == len(re.findall(r"^M[35]\b", data, re.M))


@pytest.mark.parametrize("name", ["a_long_x.gcode", "b_square.gcode", "c_circle200.gcode",
                                  "d_slicer_like.gcode", "e_spiral20k.gcode",
                                  "prusaslicer25_cube20_marlin2.gcode", "linuxcnc_plasmatest.ngc",
                                  "linuxcnc_arcspiral.ngc"])
def test_scanner_equals_python_interpreter_on_samples(name):
    path = SAMPLES / name
    if not path.exists():
        pytest.skip(f"{path} not available")
    flavor = "linuxcnc" if name.endswith(".ngc") else "marlin"
    a, ra = read_moves(str(path), Machine(flavor=flavor))
    b, rb = read_moves(str(path), Machine(flavor=flavor), force_python=True)
    assert len(a) > 0 and same_rows(a, b)
    assert ra.summary.to_json() == rb.summary.to_json()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cura413_ender3_cylinder30.gcode", "cncjs_jscut_tball_pocket_laser.gcode",
                                  "prusaslicer25_twisted_vase_spiral.gcode"])
def test_scanner_equals_python_interpreter_on_corpus(name):
    path = shared_path("gcode", name)
    a, ra = read_moves(str(path), Machine(flavor="marlin"))
    b, rb = read_moves(str(path), Machine(flavor="marlin"), force_python=True)
    assert same_rows(a, b)
    assert ra.summary.to_json() == rb.summary.to_json()


@pytest.mark.parametrize("name", ["a_long_x.gcode", "b_square.gcode", "c_circle200.gcode",
                                  "d_slicer_like.gcode", "e_spiral20k.gcode"])
def test_synthetic_samples_match_klipper_move_counts(name):
    """Klipper's [gcode_arcs] resolution is 1 mm in the reference config: same chords, same moves."""
    times = json.loads(shared_path("reference", "klipper", "synthetic", "times.json").read_text())
    path = SAMPLES / name
    m, r = read_moves(str(path), Machine(flavor="klipper", arc_resolution=1.0))
    assert r.summary.moves == times[name]["moves"]
    assert r.summary.arcs == len(re.findall(r"^G[23] ", path.read_text(), re.M))
    assert set(np.unique(m["kind"])) <= {KIND_TRAVEL, KIND_PRINT, KIND_EXTRUDE_ONLY, KIND_DWELL, KIND_WAIT}


_CHILD = """
import json, sys
from gcodeplan import cli
sys.argv[0] = "gcodeplan"            # the command's own start-up path
rc = cli.main(["parse", sys.argv[1], "--json"])
hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM:")][0].split()[1]
print(json.dumps({"rc": rc, "peak_kb": int(hwm)}))
"""


@pytest.mark.slow
def test_parse_command_streams_the_big_file_in_bounded_memory():
    """`gcodeplan parse` on the 50 MB file: peak RSS under 300 MB (the MOVE rows alone would be 236 MB).

    The child reports its own high-water mark (VmHWM, reset at exec): a forked child's ru_maxrss would
    include the size of the test process it was forked from."""
    import subprocess
    import sys
    from pathlib import Path

    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc")
    path = shared_path("gcode", "prusaslicer25_plate150_gyroid_big.gcode")
    out = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()
    summary, child = json.loads(out[0]), json.loads(out[-1])
    times = json.loads(shared_path("reference", "klipper", "times.json").read_text())
    assert child["rc"] == 0 and summary["moves"] == times[path.name]["moves"]
    assert child["peak_kb"] / 1024 < 300


def test_limits_rows_are_append_only_while_streaming(tmp_path):
    lines = []
    for i in range(50):
        lines += [f"SET_VELOCITY_LIMIT VELOCITY={100 + i}"] + [f"G1 X{j % 2} Y{i}" for j in range(30)]
    path = tmp_path / "lim.gcode"
    path.write_text("\n".join(lines) + "\n")
    r = GcodeReader(str(path), Machine(flavor="klipper"), batch_moves=64)
    seen = {}
    for b in r.batches():
        lim = r.limits
        for k in np.unique(b["limits"]):
            row = lim[k].tobytes()
            assert seen.setdefault(int(k), row) == row
            assert lim["max_v"][k] == 100 + k - 1 or k == 0
    assert len(r.limits) == 51
