"""What the Marlin model is handed per row (planner.marlin.row_inputs_kernel), worked by hand, and the
scanner's own G92 E lines (gcode.scan: no Python round trip) against the interpreter's."""
from __future__ import annotations

import numpy as np

import gcodeplan as gp
from gcodeplan.gcode import scan as S
from gcodeplan.gcode.reader import GcodeReader
from gcodeplan.planner.marlin import row_inputs_kernel
from conftest import same_rows
from gcodeplan.schema import KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL

F32 = np.float32


def _inputs(rows, sets, carry, extra=None, dwell=None, reach=(1e30,) * 4):
    """row_inputs_kernel on rows (line, kind, start xyze, end xyze, feed mm/s, accel); ``extra`` (a dict) also
    gets the row kinds, wait ticks (25 MHz) and first beyond-reach row per column; ``dwell``: dwell_t (s) per row."""
    n = len(rows)
    col = lambda k: np.array([r[k] for r in rows], dtype=np.float64)     # noqa: E731
    start = np.array([r[2] for r in rows], dtype=np.float64)
    end = np.array([r[3] for r in rows], dtype=np.float64)
    tgt, reset_pos = np.empty((n, 4), F32), np.empty((n, 4), F32)
    reset_bits, fr, acc = np.empty(n, np.int64), np.empty(n, F32), np.empty((3, n), F32)
    row_kind, wait_ticks, bad = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(8, np.int64)
    dwell_t = np.zeros(n) if dwell is None else np.array(dwell, np.float64)
    row_inputs_kernel(np.array([r[0] for r in rows], np.int64), np.array([r[1] for r in rows], np.uint8),
                      *(start[:, a] for a in range(4)), *(end[:, a] for a in range(4)), col(4), col(5), dwell_t,
                      25e6, np.array([s[0] for s in sets], np.int64), np.array([s[1] for s in sets], np.float64),
                      carry, row_kind, wait_ticks, tgt, reset_pos, reset_bits, fr, acc[0], acc[1], acc[2],
                      np.array(reach, np.float64), bad)
    if extra is not None:
        extra.update(row_kind=row_kind, wait_ticks=wait_ticks, bad=bad)
    return tgt, reset_pos, reset_bits, fr, acc


def test_row_inputs_by_hand():
    """Four rows after a G92 E0 that changes nothing (Marlin's E is already 0: gcode/feature/G92 sets nothing
    within NEAR_ZERO) and two that do: Marlin's logical E restarts at 0 where the machine E goes on; a jump of Y
    between rows (homing) sets Y; F as Marlin keeps it; the M204 P / T / R in force, each from the last row of
    its class."""
    rows = [(10, KIND_PRINT, (0, 0, 0, 0), (10, 0, 0, 1), 50.0, 2000.0),
            (12, KIND_PRINT, (10, 0, 0, 1), (20, 0, 0, 2), 50.0, 2500.0),
            (14, KIND_TRAVEL, (20, 5, 0, 2), (0, 5, 0.2, 2), np.inf, 3000.0),
            (15, KIND_EXTRUDE_ONLY, (0, 5, 0.2, 2), (0, 5, 0.2, 1.2), 35.0, 800.0),
            (16, KIND_DWELL, (0, 5, 0.2, 1.2), (0, 5, 0.2, 1.2), 0.0, np.nan)]
    # G92 E0 at line 9 (E already 0), 11 (after 1 mm: E goes 1 -> 0) and 13 (after the second 1 mm)
    sets = [(9, 0.0), (11, 0.0), (13, 0.0)]
    carry = np.array([0, 0, 0, 0, 0.0, 1000, 1500, 700], dtype=np.float64)
    tgt, reset_pos, bits, fr, acc = _inputs(rows, sets, carry)
    # E offset (machine − logical): 0, then 1 from line 11, then 2 from line 13
    assert tgt[:4, 3].tolist() == [1.0, 1.0, 0.0, F32(-0.8)]
    assert bits.tolist() == [0, 8, 8 | 2, 0, 0]             # E set at rows 1 and 2; Y jumped 0 -> 5 before row 2
    assert reset_pos[1, 3] == 0 and reset_pos[2, 3] == 0 and reset_pos[2, 1] == 5
    # F50 mm/s = 3000 mm/min, /60, ·0.01·100 in float32: 50; no F limit (rapid): 1e9 mm/min
    big = F32(F32(1e9) / F32(60))
    assert fr[0] == F32(50) and fr[2] == F32(F32(big * F32(0.01)) * F32(100))
    assert acc[0].tolist() == [2000, 2500, 2500, 2500, 2500]      # print: the last print row's
    assert acc[1].tolist() == [1500, 1500, 3000, 3000, 3000]      # travel
    assert acc[2].tolist() == [700, 700, 700, 800, 800]           # retract; a dwell sets none
    assert carry.tolist() == [0, 5, 0.2, 1.2, 2.0, 2500, 3000, 800]


def _read(text: str, machine, **kw):
    r = GcodeReader([text], machine, **kw)
    parts = list(r.batches())
    return np.concatenate(parts), list(r.interp.e_position_sets), r.interp.st.copy()


def test_scanner_g92_e_equals_the_interpreter():
    """G92 E lines the scanner interprets (more than its per-call buffer of S.ESET_MAX, so some go to Python)
    give the rows, the logical E and the (line, E) list the firmware models read, as the interpreter does; a G92
    with X, a bare G92 and a G92 E with a comment are the interpreter's or the scanner's without difference."""
    lines = ["G21", "M82", "G92 E0", "G1 X1 Y1 E0.5 F1200", "G92 X5", "G1 X6 E1", "G92", "G1 X7 E1.5",
             "G92 E0 ; reset", "G1 X8 E0.25"]
    for i in range(S.ESET_MAX + 40):
        lines += [f"G1 X{10 + i % 50} Y{i % 7} E{(i % 5) * 0.1 + 0.1:.2f}", "G92 E0" if i % 3 else "G92 E-0.5"]
    text = "\n".join(lines) + "\n"
    for name in ("marlin", "marlin-bugfix", "klipper"):
        machine = gp.load_machine(name)
        fast, sets_fast, st_fast = _read(text, machine)
        slow, sets_slow, st_slow = _read(text, machine, force_python=True)
        assert same_rows(fast, slow), name
        assert sets_fast == sets_slow, name
        keep = np.arange(S.N_ST) != S.S_MAX_E        # the exclude_object transform's; only the scanner's moves set it
        assert st_fast[keep].tobytes() == st_slow[keep].tobytes(), name
    machine = gp.load_machine("marlin")
    _, sets, _ = _read(text, machine)
    assert sets[:4] == [(3, 0.0), (9, 0.0), (12, -0.5), (14, 0.0)]
    assert len(sets) == 2 + S.ESET_MAX + 40 and all(type(ln) is int for ln, _ in sets)


def test_row_kinds_wait_ticks_and_reach_by_hand():
    """A dwell and a wait are ROW_WAIT rows, their dwell in 25 MHz ticks rounded up (1.5 µs = 37.5 ticks: 38;
    a NaN dwell: 0); moves are ROW_MOVE rows with 0 ticks. With a reach of 100 mm on X and 50 mm on E, the
    first row beyond it per column (x0, x1, y0, y1, z0, z1, e0, e1), −1 where none; a NaN counts as beyond."""
    from gcodeplan.planner import marlin_kernels as mk
    from gcodeplan.schema import KIND_WAIT

    rows = [(1, KIND_PRINT, (0, 0, 0, 0), (10, 0, 0, 60), 50.0, 2000.0),
            (2, KIND_DWELL, (10, 0, 0, 60), (10, 0, 0, 60), 0.0, np.nan),
            (3, KIND_TRAVEL, (10, 0, 0, 60), (150, 0, 0, 60), 50.0, 2000.0),
            (4, KIND_WAIT, (150, 0, 0, 60), (150, 0, 0, 60), 0.0, np.nan),
            (5, KIND_TRAVEL, (150, 0, 0, 60), (np.nan, 0, 0, 60), 50.0, 2000.0)]
    got = {}
    _inputs(rows, [], np.array([0, 0, 0, 0, 0.0, 1000, 1500, 700]), got, dwell=[0, 1.5e-6, 0, np.nan, 0],
            reach=(100.0, 1e30, 1e30, 50.0))
    assert got["row_kind"].tolist() == [mk.ROW_MOVE, mk.ROW_WAIT, mk.ROW_MOVE, mk.ROW_WAIT, mk.ROW_MOVE]
    assert got["wait_ticks"].tolist() == [0, 38, 0, 0, 0]
    assert got["bad"].tolist() == [3, 2, -1, -1, -1, -1, 1, 0]
