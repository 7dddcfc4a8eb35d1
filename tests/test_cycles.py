"""Canned cycles → moves: full point lists worked by hand from LinuxCNC's documented cycle steps."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gcodeplan.gcode.cycles import (
    MOTION_DWELL,
    MOTION_FEED,
    MOTION_RAPID,
    CycleError,
    CycleState,
    expand_cycle,
)

R, F, D = MOTION_RAPID, MOTION_FEED, MOTION_DWELL


def rows_of(*moves):
    """Expected rows from (x, y, z, motion[, dwell_s]) tuples."""
    return np.array([m + (0.0,) if len(m) == 4 else m for m in moves], dtype=float)


def check(rows, expected):
    assert rows.shape == expected.shape, f"\n{rows}\n!=\n{expected}"
    np.testing.assert_allclose(rows, expected, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- one hole of each cycle
# Common case: tool at (0, 0, 5), G98, hole at X10 Y0, R2, bottom Z−10.
START = CycleState.enter(0.0, 0.0, 5.0, retract_mode=98)


def test_g81_drill():
    rows, state = expand_cycle(81, {"X": 10, "Y": 0, "Z": -10, "R": 2}, START)
    check(rows, rows_of((10, 0, 5, R),       # rapid XY at the current height (above R)
                        (10, 0, 2, R),       # rapid down to R
                        (10, 0, -10, F),     # feed to the bottom
                        (10, 0, 5, R)))      # G98: back to the initial level
    assert (state.x, state.y, state.z) == (10, 0, 5)
    assert (state.r, state.z_word, state.code) == (2, -10, 81)


def test_g81_g99_retracts_to_r():
    rows, state = expand_cycle(81, {"X": 10, "Z": -10, "R": 2}, CycleState.enter(0, 0, 5, retract_mode=99))
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, 2, R)))
    assert state.z == 2


def test_g82_dwells_at_the_bottom():
    rows, state = expand_cycle(82, {"X": 10, "Z": -10, "R": 2, "P": 0.5}, START)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, -10, D, 0.5),
                        (10, 0, 5, R)))
    assert state.p == 0.5


def test_g83_full_retract_pecks():
    # Pecks go down from R by Q: R−Q = −2, R−2Q = −6, then the bottom −10 (R−3Q = −10 is the bottom itself).
    # After each peck: rapid out to R, rapid back to 0.254 mm above the depth just reached.
    rows, _ = expand_cycle(83, {"X": 10, "Y": 0, "Z": -10, "R": 2, "Q": 4}, START)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R),
                        (10, 0, -2, F), (10, 0, 2, R), (10, 0, -2 + 0.254, R),
                        (10, 0, -6, F), (10, 0, 2, R), (10, 0, -6 + 0.254, R),
                        (10, 0, -10, F),
                        (10, 0, 5, R)))


def test_g73_chip_break_pecks():
    rows, _ = expand_cycle(73, {"X": 10, "Z": -10, "R": 2, "Q": 4}, START, peck_retract_mm=0.5)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R),
                        (10, 0, -2, F), (10, 0, -1.5, R),
                        (10, 0, -6, F), (10, 0, -5.5, R),
                        (10, 0, -10, F),
                        (10, 0, 5, R)))


def test_peck_depth_not_a_multiple_of_q():
    # R0 Z−5 Q2: pecks −2, −4, then −5.
    rows, _ = expand_cycle(83, {"Z": -5, "R": 0, "Q": 2}, CycleState.enter(0, 0, 0, retract_mode=99))
    feeds = rows[rows[:, 3] == F][:, 2]
    assert feeds.tolist() == [-2, -4, -5]
    # Decimal Q whose multiples do not land exactly on the bottom in floating point: no sliver peck.
    rows, _ = expand_cycle(83, {"Z": -0.3, "R": 0, "Q": 0.1}, CycleState.enter(0, 0, 0, retract_mode=99))
    assert rows[rows[:, 3] == F][:, 2] == pytest.approx([-0.1, -0.2, -0.3], abs=1e-12)


def test_a_peck_count_at_the_resolution_of_r_is_refused_at_once():
    # R1e20 Z4 Q1e-6: 1e26 pecks, and r - k·q does not change with k at that magnitude (resolution 16384 mm):
    # the settling loop spun for ever before (tools/fuzz.py --seed 20261206 --replay 75283)
    with pytest.raises(CycleError, match="G83 would make 3e\\+26 moves"):
        expand_cycle(83, {"Z": 4, "R": 1e20, "Q": 1e-6}, CycleState.enter(0, 0, 0, retract_mode=99))
    with pytest.raises(CycleError, match="Q 4.94066e-324 mm is too small for a 5 mm hole"):  # subnormal Q
        expand_cycle(73, {"Z": -5, "R": 0, "Q": 5e-324}, CycleState.enter(0, 0, 0, retract_mode=99))


def test_g85_feeds_out_to_r_then_rapids_to_clear():
    rows, _ = expand_cycle(85, {"X": 10, "Z": -10, "R": 2}, START)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, 2, F), (10, 0, 5, R)))
    rows, _ = expand_cycle(85, {"X": 10, "Z": -10, "R": 2}, CycleState.enter(0, 0, 5, retract_mode=99))
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, 2, F)))


def test_g86_dwell_then_rapid_out():
    rows, _ = expand_cycle(86, {"X": 10, "Z": -10, "R": 2, "P": 1.5}, START)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, -10, D, 1.5), (10, 0, 5, R)))


def test_g89_dwell_then_feed_out():
    rows, _ = expand_cycle(89, {"X": 10, "Z": -10, "R": 2, "P": 2}, START)
    check(rows, rows_of((10, 0, 5, R), (10, 0, 2, R), (10, 0, -10, F), (10, 0, -10, D, 2.0), (10, 0, 5, F)))


# ----------------------------------------------------------------------------- modes, sticky words, repeats

def test_below_r_rapids_up_first_and_g98_clears_to_r():
    # Tool at Z0 below R2: straight up to R before any XY motion; the initial level (0) is below R, so G98
    # retracts to R.
    rows, state = expand_cycle(81, {"X": 10, "Y": 3, "Z": -4, "R": 2}, CycleState.enter(1, 1, 0))
    check(rows, rows_of((1, 1, 2, R), (10, 3, 2, R), (10, 3, -4, F), (10, 3, 2, R)))
    assert state.z == 2


def test_sticky_words_second_hole_g98_vs_g99():
    pecks = [(20, 0, -2, F), (20, 0, 2, R), (20, 0, -1.746, R), (20, 0, -3, F)]
    # G98: the first hole ends at the initial level 5; the second travels there, then rapids down to R.
    _, state = expand_cycle(83, {"X": 10, "Z": -3, "R": 2, "Q": 4}, CycleState.enter(0, 0, 5, 98))
    rows, state = expand_cycle(83, {"X": 20}, state)  # R, Z, Q are sticky
    check(rows, rows_of((20, 0, 5, R), (20, 0, 2, R), *pecks, (20, 0, 5, R)))
    assert (state.x, state.z, state.q) == (20, 5, 4)
    # G99: the first hole ends at R; the second travels at R and needs no move down to it.
    _, state = expand_cycle(83, {"X": 10, "Z": -3, "R": 2, "Q": 4}, CycleState.enter(0, 0, 5, 99))
    rows, state = expand_cycle(83, {"X": 20}, state)
    check(rows, rows_of((20, 0, 2, R), *pecks, (20, 0, 2, R)))
    assert (state.x, state.z) == (20, 2)


def test_incremental_with_l3_repeats():
    # G91 G98 G81 X10 Y5 Z−5 R−2 L3 from (0, 0, 10): R = 10 − 2 = 8, bottom = R − 5 = 3, holes at
    # (10, 5), (20, 10), (30, 15); G98 retracts to the initial level 10 between holes.
    rows, state = expand_cycle(81, {"X": 10, "Y": 5, "Z": -5, "R": -2, "L": 3},
                               CycleState.enter(0, 0, 10, retract_mode=98, incremental=True))
    def hole(x, y):
        return [(x, y, 10, R), (x, y, 8, R), (x, y, 3, F), (x, y, 10, R)]

    check(rows, rows_of(*hole(10, 5), *hole(20, 10), *hole(30, 15)))
    assert (state.x, state.y, state.z, state.l) == (30, 15, 10, 3)
    # G99: retract to R and travel there.
    rows, state = expand_cycle(81, {"X": 10, "Z": -5, "R": -2, "L": 3},
                               CycleState.enter(0, 0, 10, retract_mode=99, incremental=True))
    check(rows, rows_of((10, 0, 10, R), (10, 0, 8, R), (10, 0, 3, F), (10, 0, 8, R),
                        (20, 0, 8, R), (20, 0, 3, F), (20, 0, 8, R),
                        (30, 0, 8, R), (30, 0, 3, F), (30, 0, 8, R)))
    # A following incremental line keeps R relative to the initial level (LinuxCNC 2.8+), not to the
    # current Z (8), so the hole bottom stays at 3.
    rows, state = expand_cycle(81, {"X": 10}, state)
    check(rows, rows_of((40, 0, 8, R), (40, 0, 3, F), (40, 0, 8, R)))


def test_absolute_l2_repeats_the_same_hole():
    rows, _ = expand_cycle(81, {"X": 10, "Z": -1, "R": 1, "L": 2}, CycleState.enter(0, 0, 5))
    check(rows, rows_of((10, 0, 5, R), (10, 0, 1, R), (10, 0, -1, F), (10, 0, 5, R),
                        (10, 0, 1, R), (10, 0, -1, F), (10, 0, 5, R)))


def test_invariants_over_many_cases():
    """No XY motion below R, feeds only along Z, the last row at the clear height."""
    for code in (73, 81, 82, 83, 85, 86, 89):
        for mode in (98, 99):
            for z0 in (-1.0, 1.0, 7.0):
                words = {"X": 3, "Y": -4, "Z": -7.3, "R": 1.5, "Q": 1.1, "P": 0.2}
                rows, state = expand_cycle(code, words, CycleState.enter(0, 0, z0, mode))
                prev = np.array([0.0, 0.0, z0])
                for x, y, z, motion, _ in rows:
                    if (x, y) != tuple(prev[:2]):
                        assert motion == R and z == prev[2] >= 1.5
                    if motion == F:
                        assert (x, y) == tuple(prev[:2])
                    prev = np.array([x, y, z])
                clear = 1.5 if mode == 99 else max(z0, 1.5)
                assert rows[-1, 2] == state.z == clear
                assert rows[:, 2].min() == -7.3


# ----------------------------------------------------------------------------- errors

@pytest.mark.parametrize(
    "code, words, state, message",
    [
        (81, {"X": 1, "Z": -1}, START, "G81 needs R"),
        (81, {"X": 1, "R": 1}, START, "G81 needs Z"),
        (83, {"Z": -1, "R": 1}, START, "G83 needs Q"),
        (83, {"Z": -1, "R": 1, "Q": 0}, START, "Q must be > 0"),
        (73, {"Z": -1, "R": 1, "Q": -2}, START, "Q must be > 0"),
        (82, {"Z": -1, "R": 1}, START, "G82 needs P"),
        (89, {"Z": -1, "R": 1, "P": -1}, START, "P must be >= 0"),
        (81, {"Z": 3, "R": 1}, START, r"R plane \(1\.0000 mm\) is below the hole bottom Z \(3\.0000 mm\)"),
        (81, {"Z": -1, "R": 1, "L": 0}, START, "L must be a whole number >= 1"),
        (81, {"Z": -1, "R": 1, "L": 2.5}, START, "L must be a whole number >= 1"),
        (84, {"Z": -1, "R": 1}, START, "not a supported canned cycle"),
        (81, {"Z": float("nan"), "R": 1}, START, "not a finite number"),
        (83, {"Z": -100, "R": 0, "Q": 1e-6}, START, r"would make .* moves"),
    ],
)
def test_errors(code, words, state, message):
    with pytest.raises(CycleError, match=message):
        expand_cycle(code, words, state)


def test_changing_cycle_needs_r_and_z_again_and_plane_must_be_g17():
    _, state = expand_cycle(81, {"Z": -1, "R": 1}, START)
    with pytest.raises(CycleError, match="G82 needs"):
        expand_cycle(82, {"P": 1}, state)
    with pytest.raises(CycleError, match="canned cycles only in G17"):
        expand_cycle(81, {"Z": -1, "R": 1}, START, plane=18)
    assert math.isnan(START.r)  # the caller's state is not modified


def _rows_by_numpy(ends, x0, y0, z0, e0, e1, flags, feed_v, rapid, dwell, cnc, acc):
    """The MOVE rows of straight pieces built column by column with NumPy (independent of the kernels)."""
    from gcodeplan.schema import (FLAG_RAPID, FLAG_RETRACT, KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT,
                                  KIND_TRAVEL, MOVE_DTYPE)

    n = len(ends)
    starts = np.vstack([[x0, y0, z0], ends[:-1]])
    d = np.sqrt(((ends - starts) ** 2).sum(axis=1))
    es = e0 + (e1 - e0) * (np.arange(1, n + 1) / n)
    es[-1] = e1
    e_starts = np.concatenate([[e0], es[:-1]])
    de = es - e_starts
    xyz = d > 0.0
    a = np.zeros(n, dtype=MOVE_DTYPE)
    a["x0"], a["y0"], a["z0"], a["e0"] = starts[:, 0], starts[:, 1], starts[:, 2], e_starts
    a["x1"], a["y1"], a["z1"], a["e1"] = ends[:, 0], ends[:, 1], ends[:, 2], es
    a["line"], a["feature"], a["layer"], a["limits"], a["object"], a["exact_stop"] = 7, 3, 2, 1, 4, 1
    a["blend_p"], a["blend_q"] = 0.05, 0.01
    a["kind"] = np.where(xyz, np.where(de > 0.0, KIND_PRINT, KIND_TRAVEL), KIND_EXTRUDE_ONLY)
    a["flags"] = flags | np.where(de < 0.0, FLAG_RETRACT, 0) | np.where(rapid, FLAG_RAPID, 0)
    a["move_d"] = np.where(xyz, d, np.abs(de))
    a["feed_v"] = np.where(rapid & cnc, np.inf, feed_v)
    a["accel"] = np.where(xyz, np.where(de != 0.0, acc[0], acc[1]), acc[2])
    a["kind"][dwell] = KIND_DWELL
    for f in ("move_d", "accel", "feed_v"):
        a[f][dwell] = 0.0
    return a[xyz | (de != 0.0) | dwell]


@pytest.mark.parametrize("seed", range(20))
def test_piece_rows_equal_a_numpy_construction(seed):
    """Arc chords and canned-cycle moves become MOVE rows in two kernels (gcode/commands_motion.py, scan.py); they
    must give, bit for bit, the rows NumPy builds column by column: zero-length pieces dropped, E-only
    pieces, retractions, rapids (unlimited feed on CNC dialects) and dwells included."""
    from gcodeplan.gcode.commands_motion import pieces_through_kernel
    from gcodeplan.gcode.scan import piece_rows_kernel
    from gcodeplan.schema import FLAG_ARC, MOVE_DTYPE

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 60))
    ends = np.round(rng.uniform(-50, 50, (n, 3)), int(rng.integers(0, 4)))
    ends[rng.random(n) < 0.2] = ends[0]                          # repeated points: zero-length pieces
    start = ends[0] if rng.random() < 0.2 else rng.uniform(-50, 50, 3)      # the first piece may be empty
    x0, y0, z0 = (float(v) for v in start)
    e0, e1 = float(rng.uniform(-5, 5)), float(rng.choice([0.0, rng.uniform(-5, 5)]))
    if rng.random() < 0.3:
        e1 = e0                                                   # travel arc
    rapid = rng.random(n) < 0.3
    dwell = ~rapid & (rng.random(n) < 0.1)
    cnc = bool(rng.random() < 0.5)
    acc = (1500.0, 3000.0, 800.0)
    want = _rows_by_numpy(ends, x0, y0, z0, e0, e1, FLAG_ARC, 40.0, rapid, dwell, cnc, acc)
    from gcodeplan.gcode import scan as S

    st, ist = np.zeros(S.N_ST), np.zeros(S.N_IST, dtype=np.int64)     # the interpreter's state
    st[S.S_ACC_P], st[S.S_ACC_T], st[S.S_ACC_R] = acc
    st[S.S_BLEND_P], st[S.S_BLEND_Q] = 0.05, 0.01
    ist[S.I_FEATURE], ist[S.I_LAYER], ist[S.I_LIMITS], ist[S.I_OBJECT], ist[S.I_EXACT_STOP] = 3, 2, 1, 4, 1
    starts, d, es, e_starts = pieces_through_kernel(ends, x0, y0, z0, e0, e1)
    out = np.zeros(n, dtype=MOVE_DTYPE)
    k = piece_rows_kernel(ends, starts, es, e_starts, d, 7, FLAG_ARC, 40.0, rapid, dwell, cnc, st, ist, out)
    got = out[:k]
    assert len(got) == len(want)
    for f in MOVE_DTYPE.names:
        assert np.ascontiguousarray(got[f]).tobytes() == np.ascontiguousarray(want[f]).tobytes(), f


def test_peck_count_follows_linuxcncs_accumulation():
    """LinuxCNC convert_cycle_g83: ``for (d = r − q; d > bottom; d = d − q)``. R1 Z0 Q0.1: ten subtractions
    of 0.1 leave 1.4e-16 above the bottom, so LinuxCNC pecks ten times (the tenth a rounding error above
    the bottom) and then feeds to the bottom; R0 Z-3 Q1 subtracts exactly: pecks at -1 and -2 only."""
    rows, _ = expand_cycle(83, {"Z": 0.0, "R": 1.0, "Q": 0.1}, CycleState.enter(0, 0, 1.0, retract_mode=99))
    feeds = rows[rows[:, 3] == F, 2]
    assert len(feeds) == 11 and feeds[-2] > 0.0 and feeds[-2] < 1e-15 and feeds[-1] == 0.0
    rows, _ = expand_cycle(73, {"Z": -3.0, "R": 0.0, "Q": 1.0}, CycleState.enter(0, 0, 0.0, retract_mode=99))
    assert list(rows[rows[:, 3] == F, 2]) == [-1.0, -2.0, -3.0]
    # G73 backs off 0.254 mm above each peck (G83_RAPID_DELTA), never clamped to R (LinuxCNC)
    rows, _ = expand_cycle(73, {"Z": -1.0, "R": 0.0, "Q": 0.1}, CycleState.enter(0, 0, 0.0, retract_mode=99))
    assert rows[rows[:, 3] == R, 2].max() == pytest.approx(-0.1 + 0.254)
