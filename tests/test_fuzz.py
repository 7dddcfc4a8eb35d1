"""tools/fuzz.py: mutated real G-code through parse → plan → steps; a short round in CI, plus the fuzzer's own
machinery (reproducible cases, delta-debugging minimiser, case files that replay)."""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

import gcodeplan as gp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import fuzz  # noqa: E402

# Failures already reported and not fixed yet (their signatures); anything else fails the round. Empty: the last
# one (step times 1 ulp out of order at a piece boundary) is fixed by kernel.monotone_times.
KNOWN: tuple[str, ...] = ()


@pytest.fixture(scope="module")
def pool():
    return fuzz.load_pool(7)


def test_cases_are_reproducible_from_seed_and_index(pool):
    cfgs = fuzz.klipper_configs()
    a = [fuzz.make_case(7, i, pool, cfgs) for i in range(40)]
    b = [fuzz.make_case(7, i, pool, cfgs) for i in reversed(range(40))][::-1]
    assert a == b                                              # case i does not depend on the ones before
    assert len({tuple(c.lines) for c in a}) > 30               # and they differ
    assert {c.policy for c in a} >= {"klipper", "blend", "exact-stop"}


def test_minimiser_keeps_exactly_the_lines_that_matter(monkeypatch):
    # a failure that needs two particular lines, wherever they are: ddmin must return just those two
    lines = [b"G1 X%d" % i for i in range(40)]
    case = fuzz.Case(1, 2, lines, "klipper", None, "klipper", None, "test")

    def run_case(c, ls=None, max_steps=0):
        ls = c.lines if ls is None else ls
        return ("Bad: x", "") if b"G1 X7" in ls and b"G1 X31" in ls else None

    monkeypatch.setattr(fuzz, "run_case", run_case)
    assert fuzz.minimise(case, "Bad: x", 0) == [b"G1 X7", b"G1 X31"]


def test_a_written_case_replays_with_its_configuration(tmp_path, pool):
    case = fuzz.make_case(7, 3, pool, fuzz.klipper_configs())
    case.jerk = 1e5
    case.policy = "junction-deviation"
    path = fuzz.write_failure(tmp_path, case, "Bad: x", "traceback", case.lines[:3])
    back = fuzz.read_case(path)
    assert (back.seed, back.index, back.machine, back.flavor, back.policy, back.jerk) == \
        (case.seed, case.index, case.machine, case.flavor, case.policy, case.jerk)
    assert back.lines == case.lines[:3]


def test_the_checks_catch_a_negative_time(monkeypatch):
    # the invariant checks must fire: a planner that returned a negative phase time is a failure, not a pass
    import gcodeplan.pipeline as pipeline

    real_run = pipeline.run

    class Spoil(pipeline.Sink):
        def __init__(self, inner):
            self.inner = inner

        def add(self, piece):
            piece.plan["decel_t"][0] = -1e-19
            return self.inner.add(piece)

        def close(self, result):
            self.inner.close(result)

    def spoilt_run(source, machine, **kw):
        kw["sinks"] = [Spoil(s) for s in kw["sinks"]]
        return real_run(source, machine, **kw)

    case = fuzz.Case(0, 0, [b"G1 X10 F600", b"G1 Y10"], "klipper", None, "klipper", None, "test")
    assert fuzz.run_case(case) is None
    monkeypatch.setattr(pipeline, "run", spoilt_run)
    res = fuzz.run_case(case)
    assert isinstance(res, tuple) and res[0] == "Bad: negative PLAN.decel_t", res
    monkeypatch.undo()
    assert fuzz.run_case(fuzz.Case(0, 0, [b"G1 X10 F-600"], "klipper", None, "klipper", None, "t")) == fuzz.REJECTED


@pytest.mark.slow
def test_short_fuzz_round_finds_nothing_new(tmp_path):
    # a fixed set of cases (not a time budget): on a busy machine a timed round ran 121 cases and failed its floor
    st = fuzz.fuzz(seed=13, cases=600, seconds=None, out=tmp_path, log=print, minimise_s=10)
    assert st.cases == 600
    assert st.cases - st.rejected > 0.3 * st.cases     # a good share is planned and stepped, not refused
    new = {sig: where for sig, where in st.signatures.items() if not sig.startswith(KNOWN)}
    assert not new, new


# ----------------------------------------------------------------------------- what the fuzzer found (fixed)
def test_phase_times_are_never_negative_when_a_phase_is_absent():
    # Klipper's set_junction formulas: with no cruise, or a peak equal to the end speed that rounds a hair below
    # it, the phase distance was rounding noise below 0 (cruise / decel times of -5e-19 s)
    from gcodeplan.planner.passes import set_junction

    end_v2 = 385.24898762
    for cruise_v2 in (end_v2, np.nextafter(end_v2, 0.0), np.nextafter(np.nextafter(end_v2, 0.0), 0.0)):
        accel_d = (cruise_v2 - 80.93) / (2 * 3000.0)
        for move_d in (accel_d, np.nextafter(accel_d, 0.0)):
            times = set_junction(80.93, cruise_v2, end_v2, 3000.0, move_d)
            assert min(times) >= 0.0, (cruise_v2, move_d, times)
            # and the total still covers the distance: accel_t alone at the mean speed of the ramp
            assert sum(times) == pytest.approx(2 * accel_d / (math.sqrt(80.93) + math.sqrt(cruise_v2)), rel=1e-9)


@pytest.mark.parametrize("policy,jerk", [("klipper", None), ("junction-deviation", 1e5), ("exact-stop", None),
                                         ("blend", None), ("classic-jerk", None)])
def test_tiny_limits_are_a_clear_error_in_every_mode(policy, jerk):
    # 1e-320 squares to 0: it divided by zero (velocity) or gave inf / NaN / 0 s (acceleration; S-curves timed a
    # 123 mm move at 0 s and the estimate printed 0.000 s)
    from gcodeplan.errors import GcodeplanError

    m = gp.load_machine("marlin", firmware="generic")     # the generic policies (classic jerk: per-axis jerks)
    for first in ("SET_VELOCITY_LIMIT VELOCITY=1e-320", "SET_VELOCITY_LIMIT VELOCITY=10 ACCEL=1e-320"):
        lines = [first, "G1 X81.6 Y92.1 F600", "G1 X81.9 Y91.5", "G1 X82.2 Y90.9"]
        with pytest.raises(GcodeplanError):
            gp.estimate(lines, m, policy=policy, jerk=jerk)


def test_m486_with_an_infinite_object_number_is_a_clear_error():
    from gcodeplan.errors import GcodeplanError

    with pytest.raises(GcodeplanError, match="M486 S needs an object number"):
        gp.estimate(["M486 S-inf", "G1 X10 F600"])


def test_a_nan_time_is_not_swallowed_by_the_accounting():
    # max(total, nan) is total: a NaN duration used to vanish and the estimate printed a finite (wrong) total
    from gcodeplan.errors import GcodeError
    from gcodeplan.report.summary import TimeSummary
    from gcodeplan.schema import MOVE_DTYPE, PLAN_DTYPE

    moves = np.zeros(2, MOVE_DTYPE)
    moves["line"] = [3, 4]
    moves["move_d"] = 1.0
    plan = np.zeros(2, PLAN_DTYPE)
    plan["duration"] = [1.0, np.nan]
    plan["t_start"] = [0.0, 1.0]
    with pytest.raises(GcodeError, match="not a number") as err:
        TimeSummary().add(moves, plan)
    assert err.value.line == 4


def test_step_times_never_go_back_at_a_piece_boundary():
    """The fuzzer's minimised case: an S-curve plan whose last crossing in one piece came out one ulp after the
    next piece's first (t0 + τ against t0' + τ' with t0' = t0 + dt rounded)."""
    from dataclasses import replace

    m = replace(gp.load_machine("grbl"), flavor="klipper")
    lines = ["G1 X123.927 Y99.728 E.201", "G1 X124.502 Y99.728 E.01946", "G1 X119.728 Y104.502 E.22853"]
    steps = gp.steps(lines, m, policy="exact-stop", jerk=1e4)
    assert sum(len(t) for t, _ in steps.values()) > 50000
    for name, (t, _) in steps.items():
        assert np.all(np.diff(t) >= 0.0), name


# ----------------------------------------------------------------------------- the command-line rounds
def test_output_round_short(tmp_path):
    """tools/fuzz.py --outputs, cut to what CI affords: two commands (text and a picture) at every kind of path,
    and a full standard output (the whole round: `python tools/fuzz.py --outputs`)."""
    picked = [c for c in fuzz.OUTPUT_COMMANDS if c[0] in ("post-process -o", "plot -o")]
    st = fuzz.output_round(tmp_path, log=print, commands=picked, stdout_commands=fuzz.STDOUT_COMMANDS[:2])
    assert st["runs"] >= 2 * len(fuzz.OUTPUT_KINDS) - 2
    assert st["failures"] == []


def test_output_round_catches_a_replaced_link(tmp_path, monkeypatch):
    """The round's checks fire: an output path written the old way (os.replace over whatever the path names)
    is reported for the link to /dev/null, the FIFO and the full device."""
    picked = [c for c in fuzz.OUTPUT_COMMANDS if c[0] == "dump-moves -o"]
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "sitecustomize.py").write_text(
        "from gcodeplan.report import output as o\n"
        "def resolve(path, _real=o.resolve_output):\n"
        "    t = _real(path)\n"
        "    return o.OutputTarget('file', t.path, t.path, t.name) if t.kind == 'stream' else t\n"
        "o.resolve_output = resolve\n")
    real_env = fuzz._cli_env
    monkeypatch.setattr(fuzz, "_cli_env", lambda: dict(real_env(), PYTHONPATH=f"{shim}{os.pathsep}"
                                                                                f"{real_env()['PYTHONPATH']}"))
    st = fuzz.output_round(tmp_path / "w", log=print, commands=picked, kinds=("devnull-link", "fifo"),
                           stdout_commands=())
    assert any("null was replaced" in f for f in st["failures"]), st
    assert any("pipe was replaced" in f for f in st["failures"]), st


@pytest.mark.slow
def test_signal_round_short(tmp_path):
    """tools/fuzz.py --signals: one random signal into each command (`--long` for long rounds)."""
    st = fuzz.signal_round(seed=5, rounds=1, moves=300_000, work=tmp_path, log=print)
    assert st["runs"] == len(fuzz.signal_commands(tmp_path, tmp_path, tmp_path))
    assert st["signalled"] >= st["runs"] // 2          # most runs were really interrupted
    assert st["failures"] == []
