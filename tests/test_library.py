"""The public API (``import gcodeplan as gp``): one pipeline, the Toolhead, plug-in policies.

Truth: the planner's own whole-program plan (Toolhead and API must equal it bit for bit), Klipper's
per-line reference CSVs, the CLI's JSON, and the built-in junction kernel (registered policies).
"""
from __future__ import annotations

import csv
import gzip
import json
import random

import numba
import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES, shared_path
from gcodeplan.cli import main

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"
PLAN_FIELDS = ("t_start", "start_v", "cruise_v", "end_v", "accel", "decel", "accel_t", "cruise_t", "decel_t",
               "duration", "limit")


def _same_plan(a: np.ndarray, b: np.ndarray) -> None:
    assert len(a) == len(b)
    for f in PLAN_FIELDS:
        assert np.array_equal(a[f], b[f]), f


def _lines(path) -> list[bytes]:
    lines = path.read_bytes().split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    return lines


def test_public_names_have_docstrings_with_units():
    for name in gp.__all__:
        if name == "__version__":
            continue
        obj = getattr(gp, name)
        assert obj.__doc__ and len(obj.__doc__.strip()) > 20, name
    for fn in (gp.estimate, gp.plan, gp.steps, gp.load_machine, gp.Toolhead, gp.register_policy):
        assert any(u in fn.__doc__ for u in ("mm", " s", "(s)", "mm/s")), fn


def test_estimate_json_equals_the_cli(capsys):
    est = gp.estimate(str(CUBE))
    assert main(["estimate", "--json", "-q", str(CUBE)]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert json.loads(json.dumps(est.to_json())) == cli
    assert est.total_time_s == pytest.approx(1177.230059, abs=1e-6)     # Klipper's own total (README)


def test_line_times_equal_klippers_per_line_csv():
    ref_csv = shared_path("reference", "klipper", "per_line",
                          "prusaslicer25_cube20_marlin2.per_line_end_time.csv.gz")
    machine = gp.load_machine(klipper_config=str(shared_path("reference", "klipper", "cartesian_corpus.cfg")))
    line, end = gp.estimate(str(CUBE), machine).line_times()
    with gzip.open(ref_csv, "rt") as fh:
        rows = list(csv.reader(fh))[1:]
    ref_line = np.array([int(r[0]) for r in rows])
    ref_end = np.array([float(r[1]) for r in rows])
    assert np.array_equal(line, ref_line)                    # the same lines: those that move or dwell
    assert np.max(np.abs(end - ref_end)) <= 5e-7             # the CSV's 6 decimals


def test_plan_sample_is_the_plans_own_motion():
    p = gp.plan(str(SAMPLES / "b_square.gcode"))
    assert p.total_time_s == pytest.approx(4.123583333, abs=1e-8)     # Klipper's total
    t = np.linspace(0, p.total_time_s, 2001)
    pos, vel, acc, jerk = p.sample(t)
    assert pos.shape == (2001, 4)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    assert speed.max() <= p.plan["cruise_v"].max() + 1e-9
    # position is the integral of velocity (trapezoid rule on a fine grid)
    integ = np.cumsum((vel[1:, 0] + vel[:-1, 0]) / 2 * np.diff(t))
    assert np.allclose(pos[1:, 0] - pos[0, 0], integ, atol=5e-3)   # velocity is piecewise linear: exact but at kinks


@pytest.mark.parametrize("policy,jerk", [(None, None), ("junction-deviation", None), ("classic-jerk", None),
                                         ("blend", None), ("exact-stop", None), (None, 50000.0)])
def test_toolhead_line_by_line_equals_plan(policy, jerk):
    machine = gp.load_machine("marlin" if policy == "classic-jerk" else "klipper")
    ref = gp.plan(str(CUBE), machine, policy=policy, jerk=jerk)
    th = gp.Toolhead(machine, policy=policy, jerk=jerk, block_lines=97)
    for line in _lines(CUBE):
        th.gcode(line)
    th.close()
    moves, plan = th.committed_arrays()
    _same_plan(plan, ref.plan)
    assert np.array_equal(moves["line"], ref.moves["line"])


def test_toolhead_random_chunks_and_lazy_commit():
    ref = gp.plan(str(SAMPLES / "d_slicer_like.gcode"))
    lines = _lines(SAMPLES / "d_slicer_like.gcode")
    rng = random.Random(7)
    th = gp.Toolhead(block_lines=1)
    got = []
    k = 0
    while k < len(lines):
        n = rng.randint(1, 40)
        th.gcode(b"\n".join(lines[k:k + n]))
        k += n
        got.extend(th.committed())
        # what is committed never changes later: the prefix so far equals the whole-file plan
        if got:
            assert got[-1].end_time == pytest.approx(float(ref.plan["t_start"][len(got) - 1]
                                                           + ref.plan["duration"][len(got) - 1]), abs=0)
    th.close()
    got.extend(th.committed())
    assert [m.line for m in got] == ref.moves["line"].tolist()
    assert [m.end_v for m in got] == ref.plan["end_v"].tolist()
    assert got[-1].end_time == pytest.approx(43.283454874, abs=1e-8)   # Klipper's total for this file


def test_toolhead_firmware_loop_on_the_cube_equals_plan():
    # th.gcode(line) then th.committed() per line, as a firmware loop would: the CommittedMove objects, every
    # field, equal the whole-file plan's rows bit for bit (index, line, kind, end position, speeds, times, limit).
    from gcodeplan.schema import KIND_NAMES, LIMIT_NAMES

    ref = gp.plan(str(CUBE))
    th = gp.Toolhead()
    got = []
    for line in _lines(CUBE):
        th.gcode(line)
        got.extend(th.committed())
    th.close()
    got.extend(th.committed())
    m, p = ref.moves, ref.plan
    assert [g.index for g in got] == list(range(len(p)))
    assert [g.line for g in got] == m["line"].tolist()
    assert [g.kind for g in got] == [KIND_NAMES[k] for k in m["kind"]]
    assert [g.limit for g in got] == [LIMIT_NAMES[k] for k in p["limit"]]
    for attr, col in (("x", m["x1"]), ("y", m["y1"]), ("z", m["z1"]), ("e", m["e1"]), ("move_d", m["move_d"]),
                      ("start_v", p["start_v"]), ("cruise_v", p["cruise_v"]), ("end_v", p["end_v"]),
                      ("accel", p["accel"]), ("start_time", p["t_start"]), ("end_time", p["t_start"] + p["duration"])):
        assert np.array_equal(np.array([getattr(g, attr) for g in got]), col), attr


def test_toolhead_hands_out_the_exact_commits_of_each_block():
    # committed() sees what the blocks of block_lines lines interpreted so far made final: after line k it has
    # handed out exactly what a Toolhead interpreting every line (block_lines=1) had made final after the
    # last whole block, never a move whose speeds could still change, and in the end the same moves.
    lines = _lines(SAMPLES / "d_slicer_like.gcode")
    exact, lazy = gp.Toolhead(block_lines=1), gp.Toolhead(block_lines=50)
    n_exact, n_lazy = [], []
    got_exact, got_lazy = [], []
    for line in lines:
        for th, got, n in ((exact, got_exact, n_exact), (lazy, got_lazy, n_lazy)):
            th.gcode(line)
            got.extend(th.committed())
            n.append(len(got))
    assert n_lazy[48] == 0 < n_exact[48]                 # 49 lines: nothing interpreted yet
    for k in range(len(lines)):
        boundary = (k + 1) // 50 * 50 - 1                # the last line of the last whole block
        assert n_lazy[k] == (n_exact[boundary] if boundary >= 0 else 0), k
    for th, got in ((exact, got_exact), (lazy, got_lazy)):
        th.close()
        got.extend(th.committed())
    assert got_lazy == got_exact                         # dataclass equality: every field, bit for bit


def _toolhead_steps(machine, lines, **kw):
    """th.steps() read after every line of a firmware loop, concatenated per stepper."""
    th = gp.Toolhead(machine, steps=True, **kw)
    parts = {}
    for line in lines:
        th.gcode(line)
        th.committed()
        for name, td in th.steps().items():
            parts.setdefault(name, []).append(td)
    th.close()
    for name, td in th.steps().items():
        parts.setdefault(name, []).append(td)
    return {name: (np.concatenate([t for t, _ in p]), np.concatenate([d for _, d in p])) for name, p in parts.items()}


@pytest.mark.parametrize("machine,head,kw", [
    ("klipper", [], {}),
    ("marlin-2.1.2", [], {"block_lines": 97}),          # the firmware model's own stepper pulses
    ("klipper", ["SET_INPUT_SHAPER SHAPER_FREQ_X=45 SHAPER_FREQ_Y=38", "SET_PRESSURE_ADVANCE ADVANCE=0.05"],
     {"block_lines": 37, "sds_filter": 750e-9}),
])
def test_toolhead_steps_equal_gp_steps(machine, head, kw):
    # the steps of what became final, read as the loop goes, are gp.steps' on the same program, bit for bit
    lines = [h.encode() for h in head] + _lines(CUBE)[:2500]
    m = gp.load_machine(machine)
    ref = gp.steps([ln.decode() for ln in lines], m, sds_filter=kw.get("sds_filter"))
    got = _toolhead_steps(m, lines, **kw)
    assert set(got) == set(ref)
    for name, (t, d) in ref.items():
        assert len(t) > 1000, name
        assert np.array_equal(got[name][0], t) and np.array_equal(got[name][1], d), name


@pytest.mark.parametrize("policy,jerk", [(None, None), ("blend", None), (None, 50000.0)])
def test_toolhead_hands_pipeline_sinks_the_pieces_of_gp_run(policy, jerk):
    # a pipeline sink on a Toolhead fed line by line gets what pipeline.run gives it on the file: the same MOVE,
    # PLAN and SEGMENT rows (blend / S-curve pieces included, which exist only while the sink is called), closed once
    m = gp.load_machine("klipper")
    ref = gp.pipeline.Collect()
    gp.pipeline.run(str(CUBE), m, policy=policy, jerk=jerk, sinks=[ref])
    closed = []

    class Sink(gp.pipeline.Collect):
        def close(self, result):
            closed.append(result.rows)

    sink = Sink()
    th = gp.Toolhead(m, policy=policy, jerk=jerk, sinks=[sink])
    for line in _lines(CUBE):
        th.gcode(line)
        th.committed()
    th.close()
    for a, b in zip(sink.arrays(), ref.arrays()):
        assert len(a) == len(b)
        # MOVE.layer aside: the reader numbers layers by comments only when its first chunk holds a layer comment
        # (gcode/reader.py), which text fed a line at a time cannot show it in advance
        for f in (f for f in a.dtype.names if f != "layer"):
            assert np.array_equal(a[f], b[f], equal_nan=True), f
    assert closed == [len(ref.arrays()[0])]


def test_toolhead_steps_need_to_be_asked_for():
    with pytest.raises(RuntimeError, match="steps=True"):
        gp.Toolhead().steps()


def test_toolhead_flush_is_a_full_stop_and_move_is_a_g1_line():
    th = gp.Toolhead("klipper")
    th.move(x=10, y=0, speed=100)
    th.move(x=20, y=0)
    th.flush()
    first = th.committed()
    assert first[-1].end_v == 0.0 and first[0].start_v == 0.0
    assert first[0].cruise_v == pytest.approx(100.0)
    th.gcode("G1 X30")
    th.close()
    second = th.committed()
    assert second[0].start_v == 0.0                  # the flush stopped the head
    assert second[0].start_time == pytest.approx(first[-1].end_time)
    # the same text through gp.plan, with an M400 (Klipper's full stop) where flush() was
    ref = gp.plan(["G1 X10.0 Y0.0 F6000.0", "G1 X20.0 Y0.0", "M400", "G1 X30"])
    ends = ref.plan["t_start"] + ref.plan["duration"]
    assert second[-1].end_time == pytest.approx(float(ends.max()), abs=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cura413_ender3_cylinder30.gcode", "prusaslicer25_twisted_vase_spiral.gcode",
                                  "prusaslicer25_multi_object_plate_relE.gcode", "cncjs_jscut_tball_pocket_laser.gcode",
                                  "prusaslicer25_plate150_gyroid_big.gcode"])
def test_toolhead_equals_plan_on_the_corpus(name):
    from gcodeplan.gcode.dialect import reading_machine

    path = shared_path("gcode", name)
    # a named file on the default machine is read with the meanings of its dialect (the jscut file: grbl's);
    # a Toolhead has no file to look at: give it the machine the file is read with
    machine, _, _ = reading_machine(str(path), gp.load_machine())
    sink = gp.pipeline.Collect(segments=False)
    gp.pipeline.run(str(path), gp.load_machine(), sinks=[sink])
    _, ref_plan, _ = sink.arrays()
    th = gp.Toolhead(machine)
    with open(path, "rb") as fh:
        for line in fh:                 # one line per call, as a host feeding a firmware
            th.gcode(line)
    th.close()
    _, plan = th.committed_arrays()
    _same_plan(plan, ref_plan)


# ----------------------------------------------------------------------------- policies as plug-ins
def _user_jd():
    import math

    from gcodeplan.planner.policies import ACCEL, JUNCTION_DEV, KINEMATIC, MOVE_D, U_X, U_Y, U_Z

    @numba.njit
    def cap(prev, cur, lim):
        if prev[KINEMATIC] == 0.0 or cur[KINEMATIC] == 0.0:
            return 0.0
        cos_theta = -(cur[U_X] * prev[U_X] + cur[U_Y] * prev[U_Y] + cur[U_Z] * prev[U_Z])
        if cos_theta > 0.999999:
            return 0.0
        if cos_theta < -0.999999:
            return math.inf
        s = math.sqrt(0.5 * (1.0 - cos_theta))
        v2 = cur[ACCEL] * cur[JUNCTION_DEV] * s / (1.0 - s)
        if cur[MOVE_D] < 1.0 and cos_theta < -0.7071067812:
            turn = max(math.acos(min(1.0, max(-1.0, -cos_theta))), 0.033)
            v2 = min(v2, cur[MOVE_D] * cur[ACCEL] / turn)
        return v2

    return cap


@pytest.fixture
def registered():
    names = []

    def reg(name, fn, **kw):
        gp.register_policy(name, fn, **kw)
        names.append(name)

    yield reg
    for n in names:
        gp.unregister_policy(n)


def test_a_registered_policy_equal_to_junction_deviation_plans_identically(registered):
    registered("my-jd", _user_jd())
    for path in (CUBE, SAMPLES / "e_spiral20k.gcode"):
        _same_plan(gp.plan(str(path), policy="my-jd").plan, gp.plan(str(path), policy="junction-deviation").plan)


@pytest.mark.parametrize("name", ["klipper", "junction-deviation", "classic-jerk"])
def test_builtins_through_the_plugin_door_equal_their_kernels(registered, name):
    from gcodeplan.planner import policies

    builtin = policies.get_policy(name)
    registered(f"door-{name}", builtin.cap_v2, moves_like=name)
    # classic jerk needs per-axis jerks: the marlin machine, planned by the generic policy (the preset's
    # firmware model would plan with Marlin's own rule whatever the policy's name)
    machine = gp.load_machine("marlin", firmware="generic") if name == "classic-jerk" else gp.load_machine()
    _same_plan(gp.plan(str(CUBE), machine, policy=f"door-{name}").plan, gp.plan(str(CUBE), machine, policy=name).plan)


def test_a_registered_policy_is_usable_from_the_cli_and_bad_ones_are_refused(registered, capsys):
    registered("stop-all", lambda prev, cur, lim: 0.0)
    assert main(["estimate", "--json", "-q", "--policy", "stop-all", str(SAMPLES / "b_square.gcode")]) == 0
    stop_all = json.loads(capsys.readouterr().out)["total_time_s"]
    assert main(["estimate", "--json", "-q", "--policy", "exact-stop", str(SAMPLES / "b_square.gcode")]) == 0
    assert stop_all == pytest.approx(json.loads(capsys.readouterr().out)["total_time_s"], rel=1e-12)
    with pytest.raises(gp.GcodeplanError):
        gp.register_policy("klipper", lambda p, c, l: 0.0)          # built-ins cannot be replaced
    with pytest.raises(gp.GcodeplanError):
        gp.register_policy("x", lambda p, c, l: 0.0, moves_like="nope")
    with pytest.raises(gp.GcodeplanError):
        gp.estimate(str(CUBE), policy="never-registered")


def test_sources_other_than_paths():
    text = (SAMPLES / "b_square.gcode").read_text()
    a = gp.estimate(text.splitlines()).total_time_s
    assert a == gp.estimate(str(SAMPLES / "b_square.gcode")).total_time_s


def test_cli_plugin_registers_a_policy_in_the_command_line(tmp_path, capsys):
    plugin = tmp_path / "my_rules.py"
    plugin.write_text("import gcodeplan as gp\n"
                      "gp.register_policy('plugin-stop', lambda prev, cur, lim: 0.0, replace=True)\n")
    f = str(SAMPLES / "b_square.gcode")
    try:
        assert main(["estimate", "--json", "-q", "--plugin", str(plugin), "--policy", "plugin-stop", f]) == 0
        ours = json.loads(capsys.readouterr().out)
        assert ours["policy"] == "plugin-stop"
        assert main(["estimate", "--json", "-q", "--policy", "exact-stop", f]) == 0
        assert ours["total_time_s"] == pytest.approx(json.loads(capsys.readouterr().out)["total_time_s"], rel=1e-12)
    finally:
        gp.unregister_policy("plugin-stop")
    assert main(["estimate", "--plugin", str(tmp_path / "missing.py"), f]) == 2
    assert "--plugin" in capsys.readouterr().err


def test_load_machine_reads_a_linuxcnc_ini_and_plans_as_linuxcnc():
    m = gp.load_machine(linuxcnc_ini=str(shared_path("reference", "linuxcnc", "config", "mill.ini")))
    assert m.junction_policy == "linuxcnc"
    est = gp.estimate(str(SAMPLES / "linuxcnc_plasmatest.ngc"), m)
    assert est.total_time_s == pytest.approx(79.275, rel=5e-3)       # LinuxCNC 2.9's own (noidle) total
    with pytest.raises(gp.GcodeplanError):
        gp.load_machine("klipper", linuxcnc_ini="x.ini")
