"""The firmware models' per-batch kernels (issue 21's speed work) against plain NumPy written the obvious way:
the grbl mode's one-pass batch check, its op-array append, the Marlin window's row copy, and the stream's
unread PREP rows. The models' results against the firmware are tests/test_marlin*.py and tests/test_grbl*.py."""
import numpy as np

from gcodeplan.planner.grbl import N_INFO, _append_ops_kernel, _first_refused_kernel
from gcodeplan.planner.marlin import window_rows_kernel
from gcodeplan.planner.marlin_kernels import N_OF, N_OI
from gcodeplan.planner.prepare import PREP_DTYPE
from gcodeplan.planner.prepare import unread_prep


def _refused_numpy(e0, e1, x1, y1, z1, reach):
    """(first E move, axis, row): the E check, then the first axis (X, Y, Z) with a target not within its reach
    (NaN counts as beyond), that axis' first such row."""
    moves_e = np.nonzero(e1 != e0)[0]
    e_row = int(moves_e[0]) if moves_e.size else -1
    for k, v in enumerate((x1, y1, z1)):
        bad = np.nonzero(~(np.abs(v) < reach[k]))[0]
        if bad.size:
            return e_row, k, int(bad[0])
    return e_row, -1, -1


def test_grbl_batch_check_matches_the_two_checks_it_replaces():
    rng = np.random.default_rng(21)
    reach = np.array([100.0, 50.0, 10.0])
    specials = np.array([np.nan, np.inf, -np.inf, 100.0, -50.0, 1e300])
    for trial in range(300):
        n = int(rng.integers(0, 40))
        cols = [rng.uniform(-9, 9, n) for _ in range(5)]         # e0, e1, x1, y1, z1
        cols[1] = cols[0].copy()
        for c in range(5):                                       # a few E moves, far targets, NaN / inf
            hit = rng.random(n) < 0.03
            cols[c][hit] = rng.choice(specials, hit.sum())
        got = tuple(int(v) for v in _first_refused_kernel(*cols, reach))
        assert got == _refused_numpy(*cols, reach), trial


def test_grbl_batch_check_by_hand():
    """Y beyond its reach on row 1, X on row 3, an E move on row 4: the E move is named (the E check comes first),
    and of the reach errors X's (axes in order X, Y, Z), on its first row."""
    e0 = np.zeros(5)
    e1 = np.array([0.0, 0.0, 0.0, 0.0, 2.0])
    x1 = np.array([1.0, 2.0, 3.0, 1e9, 5.0])
    y1 = np.array([0.0, np.nan, 0.0, 0.0, 0.0])
    z1 = np.zeros(5)
    reach = np.array([1e6, 1e6, 1e6])
    assert tuple(int(v) for v in _first_refused_kernel(e0, e1, x1, y1, z1, reach)) == (4, 0, 3)
    assert tuple(int(v) for v in _first_refused_kernel(e0[:3], e0[:3], x1[:3], y1[:3], z1[:3], reach)) == (-1, 1, 1)
    assert tuple(int(v) for v in _first_refused_kernel(e0[:1], e0[:1], x1[:1], y1[:1], z1[:1], reach)) == (-1, -1, -1)


def test_grbl_op_append_as_concatenation():
    """Two pending ops (global 7, 8) and a batch of 4 rows whose rows 0, 2, 3 make ops 9, 10, 11."""
    row_op = np.array([-1, 7, 8], np.int64)
    kind = np.array([1, 2], np.int64)
    rapid = np.array([True, False])
    end = np.array([1234, -1], np.int64)
    info = np.arange(2 * N_INFO, dtype=np.float32).reshape(2, N_INFO)
    new_rows = np.array([0, 2, 3], np.int64)
    new_kind = np.array([1, 1, 2], np.int64)
    new_rapid = np.array([False, True, False])
    r2, k2, ra2, e2, i2 = _append_ops_kernel(row_op, kind, rapid, end, info, 4, new_rows, new_kind, new_rapid, 9)
    assert r2.tolist() == [-1, 7, 8, 9, -1, 10, 11]
    assert k2.tolist() == [1, 2, 1, 1, 2]
    assert ra2.tolist() == [True, False, False, True, False]
    assert e2.tolist() == [1234, -1, -1, -1, -1]
    assert np.array_equal(i2[:2], info) and not i2[2:].any() and i2.dtype == np.float32
    assert row_op.tolist() == [-1, 7, 8] and end.tolist() == [1234, -1]      # the old arrays are left alone


def test_marlin_window_rows_copy_clear_and_flag():
    n = 5
    limits = np.array([0, 0, 1, 1, 2], np.int64)
    line = np.array([3, 4, 4, 9, 12], np.int64)
    kind = np.array([1, 2, 1, 5, 1], np.uint8)
    move_d = np.array([1.5, 0.0, 2.25, 0.0, 7.0])
    ones = np.ones(n, np.float32)
    outs = [np.full(n, -5, np.int64), np.full(n, -5, np.int64), np.full(n, 9, np.uint8), np.full(n, -5.0)]
    out_i = np.full((n, N_OI), 77, np.int64)
    out_f = np.full((n, N_OF), 7.0, np.float32)
    assert not window_rows_kernel(limits, line, kind, move_d, ones, ones, ones, ones, *outs, out_i, out_f)
    assert outs[0].tolist() == limits.tolist() and outs[1].tolist() == line.tolist()
    assert outs[2].tolist() == kind.tolist() and outs[3].tolist() == move_d.tolist()
    assert not out_i.any() and not out_f.any()
    # the flag: some feed rate or acceleration handed on is 0 or less (a NaN is not: as (a <= 0).any())
    for col in range(4):
        for bad, flagged in ((0.0, True), (-1.0, True), (np.nan, False), (1e-45, False)):
            vals = [ones.copy() for _ in range(4)]
            vals[col][3] = bad
            got = window_rows_kernel(limits, line, kind, move_d, *vals, *outs, out_i, out_f)
            assert bool(got) == flagged, (col, bad)


def test_unread_prep_rows_are_zero_and_cost_no_memory():
    p = unread_prep(100_000)
    assert p.dtype == PREP_DTYPE and len(p) == 100_000
    assert p.strides == (0,) and not p.flags.writeable
    assert all(not np.any(p[name]) for name in PREP_DTYPE.names)
    assert len(unread_prep(0)) == 0
