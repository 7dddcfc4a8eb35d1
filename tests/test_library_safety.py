"""The library refuses what would silently go wrong: numbers G-code would misread, a Toolhead shared by
threads, arguments of the wrong type, plug-in policies returning nonsense, unsorted sample times.

Truth: G-code's own reading of a number (the interpreter given the same text), the whole-program plan
(a Toolhead must equal it bit for bit however it is fed), hand-written expectations for the errors.
"""
from __future__ import annotations

import math
import threading

import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES
from gcodeplan.errors import GcodeError
from gcodeplan import toolhead

CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"


# ----------------------------------------------------------------------------- numbers written as G-code
@pytest.mark.parametrize("v,text", [(0.00001, "0.00001"), (5e-5, "0.00005"), (1e20, "100000000000000000000"),
                                    (-2.5e-7, "-0.00000025"), (10.0, "10"), (0.1, "0.1"), (123.456, "123.456"),
                                    (1e16, "10000000000000000"), (-0.0, "-0")])
def test_gcode_number_is_a_plain_decimal(v, text):
    assert toolhead.gcode_number(v) == text
    assert float(text) == v                          # round-trips to the very same float


@pytest.mark.parametrize("v", [1e-5, 5e-5, 1e20, 3e-300, 1.7976931348623157e308, 0.1 + 0.2, -1e-7, 2.0 ** -40])
def test_gcode_number_round_trips(v):
    text = toolhead.gcode_number(v)
    assert "e" not in text.lower() and float(text) == v


def test_move_with_a_tiny_coordinate_is_that_move_not_a_retraction():
    # "G1 X1e-05" reads as X1 E-05: a 1 mm move and a retraction. The move written by move() must be
    # the move asked for: X = 0.00001 mm, E untouched.
    th = gp.Toolhead("marlin")
    th.gcode("G21 G90 M82\nG1 X5 Y5 F3000")
    th.move(x=0.00001, y=5)
    th.move(x=1e-5, y=6, e=5e-5)
    th.close()
    moves, _ = th.committed_arrays()
    assert moves["x1"][-2] == 0.00001 and moves["e1"][-2] == 0.0
    assert moves["x1"][-1] == 1e-5 and moves["e1"][-1] == 5e-5
    ref = gp.plan(["G21 G90 M82", "G1 X5 Y5 F3000", "G1 X0.00001 Y5", "G1 X0.00001 Y6 E0.00005"], "marlin")
    assert np.array_equal(moves["x1"], ref.moves["x1"]) and np.array_equal(moves["e1"], ref.moves["e1"])


def test_move_with_a_huge_coordinate_is_that_huge_move():
    # "G1 X1e+20" reads as X1 E+20; written in full it is the 1e20 mm move, which the planner refuses by name
    from gcodeplan.config import without_bounds

    th = gp.Toolhead(without_bounds(gp.load_machine("marlin")))
    th.move(x=1e20, speed=100)
    with pytest.raises(GcodeError, match=r"a move of 1e\+20 mm"):
        th.close()


@pytest.mark.parametrize("kw", [dict(x=math.nan), dict(y=math.inf), dict(e=-math.inf), dict(z=float("nan")),
                                dict(x=1, speed=math.nan), dict(x=1, speed=math.inf)])
def test_move_refuses_non_finite_values(kw):
    th = gp.Toolhead()
    with pytest.raises(ValueError, match="finite"):
        th.move(**kw)
    th.close()
    assert len(th.committed()) == 0                   # nothing was queued


@pytest.mark.parametrize("speed", [0, -5.0])
def test_move_refuses_a_speed_that_is_not_positive(speed):
    with pytest.raises(ValueError, match="speed must be > 0"):
        gp.Toolhead().move(x=1, speed=speed)


@pytest.mark.parametrize("bad", [123, 1.5, None, ["G1 X1"], object()])
def test_gcode_of_a_non_text_argument_is_a_type_error(bad):
    th = gp.Toolhead()
    with pytest.raises(TypeError, match="str or bytes"):
        th.gcode(bad)
    with pytest.raises(TypeError):
        th.move(x="10")


def test_gcode_accepts_bytes_like():
    th = gp.Toolhead()
    th.gcode(bytearray(b"G1 X10 F6000"))
    th.gcode(memoryview(b"G1 X20"))
    th.close()
    assert [m.x for m in th.committed()] == [10.0, 20.0]


# ----------------------------------------------------------------------------- threads
def test_toolhead_fed_and_drained_from_two_threads_equals_the_plan():
    # A producer feeds the cube line by line while a consumer drains committed() as fast as it can:
    # with the lock, the rows handed out are exactly the whole-file plan, in order, none lost or doubled.
    lines = CUBE.read_bytes().split(b"\n")
    ref = gp.plan(str(CUBE), "marlin")
    th = gp.Toolhead("marlin", block_lines=1)
    got_plan, got_moves, errors = [], [], []
    done = threading.Event()

    def consume():
        try:
            while not done.is_set():
                m, p = th.committed_arrays()
                got_moves.append(m)
                got_plan.append(p)
        except BaseException as err:      # noqa: BLE001 - reported below
            errors.append(err)

    def produce(part):
        try:
            for ln in part:
                th.gcode(ln)
        except BaseException as err:      # noqa: BLE001
            errors.append(err)

    consumer = threading.Thread(target=consume)
    consumer.start()
    # two producers in turn (the second starts once the first is done): the text order is kept
    for part in (lines[: len(lines) // 2], lines[len(lines) // 2:]):
        t = threading.Thread(target=produce, args=(part,))
        t.start()
        t.join()
    th.close()
    done.set()
    consumer.join()
    m, p = th.committed_arrays()
    got_moves.append(m)
    got_plan.append(p)
    assert not errors, errors
    plan = np.concatenate(got_plan)
    moves = np.concatenate(got_moves)
    assert len(plan) == len(ref.plan)
    assert np.array_equal(moves["line"], ref.moves["line"])
    assert np.array_equal(plan["t_start"], ref.plan["t_start"])
    assert np.array_equal(plan["end_v"], ref.plan["end_v"])


def test_toolhead_two_feeding_threads_keep_a_consistent_state():
    # Two threads feed whole moves (each call one line) and drain at once: every line fed is planned
    # exactly once (row count = lines fed), the clock is the sum of the durations.
    th = gp.Toolhead("klipper", block_lines=1)
    th.gcode("G90 G1 F6000")
    rows, errors = [], []
    n_per_thread = 600

    def work(k):
        try:
            for i in range(n_per_thread):
                th.gcode(f"G1 X{(i % 50) + 1} Y{k * 10 + (i % 7)}")
                rows.extend(th.committed())
        except BaseException as err:      # noqa: BLE001
            errors.append(err)

    ts = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    th.close()
    rows.extend(th.committed())
    assert not errors, errors
    assert sorted(r.index for r in rows) == list(range(len(rows)))
    assert len(rows) == 2 * n_per_thread
    assert th.print_time == max(r.end_time for r in rows)


# ----------------------------------------------------------------------------- plug-in policies
def _plugin(name, value):
    import numba

    @numba.njit
    def cap(prev, cur, lim):
        return value

    gp.register_policy(name, cap, replace=True)


@pytest.mark.parametrize("value,what", [(math.nan, "NaN"), (-1.0, "negative"), (-math.inf, "negative")])
def test_policy_returning_nan_or_a_negative_speed_is_an_error_naming_it(value, what):
    name = f"bad-{what}-{value}"
    _plugin(name, value)
    try:
        with pytest.raises(GcodeError) as err:
            gp.estimate(["G1 X10 F6000", "G1 X20 Y5", "G1 X30"], policy=name)
        msg = str(err.value)
        assert name in msg and what in msg and msg.startswith("<lines>:2: ") and "\n" not in msg
        with pytest.raises(GcodeError, match=name):
            th = gp.Toolhead(policy=name)
            th.gcode("G1 X10 F6000\nG1 X20 Y5\nG1 X30")
            th.close()
    finally:
        gp.unregister_policy(name)


def test_policy_returning_zero_or_inf_is_fine():
    for value in (0.0, math.inf):
        name = f"ok-{value}"
        _plugin(name, value)
        try:
            est = gp.estimate(["G1 X10 F6000", "G1 X20 Y5", "G1 X30"], policy=name)
            assert est.total_time_s > 0
        finally:
            gp.unregister_policy(name)


# ----------------------------------------------------------------------------- Plan.sample
def test_plan_sample_says_times_must_be_sorted():
    p = gp.plan(["G1 X10 F6000", "G1 X20"])
    assert "ascending" in gp.Plan.sample.__doc__ and "ValueError" in gp.Plan.sample.__doc__
    with pytest.raises(ValueError, match=r"sorted ascending.*times\[2\] = 0\.1 comes after times\[1\] = 0\.2"):
        p.sample([0.0, 0.2, 0.1])
    with pytest.raises(ValueError, match=r"NaN"):
        p.sample([0.0, math.nan])
    pos, vel, _, _ = p.sample(np.sort(np.array([0.3, 0.0, 0.1])))      # sorting first is the fix it names
    assert pos[0, 0] == 0.0 and pos.shape == (3, 4)
