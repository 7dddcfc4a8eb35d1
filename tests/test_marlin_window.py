"""The Marlin model's window (planner.marlin.MarlinModel): the rows read and not yet settled live in buffers reused
from batch to batch, and the reach check runs in the row-inputs kernel's pass. Batches of any size, down to one
row, give the PLAN rows of the whole program fed at once, and the firmware's total; an end point beyond the
int32 step positions is reported for the first column in X0, X1, Y0 … E1 order, on that column's first line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import shared_path

CUBE = "prusaslicer25_cube20_marlin2"


def _moves(machine_name: str, n_rows: int | None = None):
    import gcodeplan as gp
    from gcodeplan.gcode.reader import read_moves

    path = shared_path("gcode", CUBE + ".gcode")
    if not path.exists():
        pytest.skip("shared G-code corpus not available")
    machine = gp.load_machine(machine_name)
    moves, reader = read_moves(str(path), machine)
    return machine, moves[:n_rows] if n_rows else moves, reader


@pytest.mark.parametrize("machine_name", ["marlin-2.1.2", "marlin-bugfix"])
def test_batches_of_any_size_give_the_whole_programs_rows(machine_name):
    """The cube fed in batches of 1 … 3000 rows (the buffers grow, and the unsettled rows move to their front
    after every batch) gives, row for row, the PLAN rows of the program fed in one batch, whose total is the
    firmware's own (shared/reference/marlin times.json)."""
    from collections import deque

    from gcodeplan.planner.marlin import MarlinModel

    machine, moves, reader = _moves(machine_name)
    sets = list(reader.interp.e_position_sets)
    whole = MarlinModel(machine, e_position_sets=deque(sets))
    ref = np.concatenate([p for _, p in whole.feed(moves, reader.limits) + whole.finish()])
    model = MarlinModel(machine, e_position_sets=deque(sets))
    rng = np.random.default_rng(5)
    pieces, i = [], 0
    while i < len(moves):
        n = int(rng.choice([1, 2, 7, 16, 100, 3000]))
        pieces += model.feed(moves[i:i + n], reader.limits)
        i += n
    pieces += model.finish()
    got = np.concatenate([p for _, p in pieces])
    assert sum(n for n, _ in pieces) == len(moves) == len(got)
    for f in got.dtype.names:
        assert np.array_equal(got[f], ref[f], equal_nan=True), f
    times = json.loads(shared_path("reference", "marlin", "times.json").read_text())[CUBE + ".gcode"]
    want = times["bugfix-2.1.x" if machine_name == "marlin-bugfix" else "marlin-2.1.2.4"]["total_time_s"]
    end = got["t_start"] + got["duration"]
    assert end.max() == pytest.approx(want, abs=1e-8)


def test_reach_error_names_the_first_column_then_its_first_line():
    """Two rows beyond the reach of Marlin's int32 steps in one batch: E (1e20 mm) on line 2, Y (1e308 mm, set
    by SET_KINEMATIC_POSITION) on line 4. Y comes before E in the column order, so Y on line 4 is reported;
    without the Y row, E on line 2."""
    import gcodeplan as gp
    from gcodeplan.errors import GcodeError

    from gcodeplan.config import without_bounds

    # without travel limits: Marlin's software endstops would clamp the Y of 1e308 to 212.5 before the planner
    m = without_bounds(gp.load_machine("marlin"))
    prog = ["G1 X1 Y1 E1 F600", "G1 X2 Y1 E99999999999999999999", "SET_KINEMATIC_POSITION X=0 Y=1e308 Z=0", "G1 X200 F6000"]
    with pytest.raises(GcodeError, match=r"Y 1e\+308 mm is beyond Marlin's reach") as err:
        gp.plan(prog, m)
    assert err.value.line == 4
    with pytest.raises(GcodeError, match=r"E 1e\+20 mm is beyond Marlin's reach") as err:
        gp.plan(prog[:2], m)
    assert err.value.line == 2
