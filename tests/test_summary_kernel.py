"""TimeSummary's one-pass kernel gives, bit for bit, what NumPy's formulation of the same totals gives.

The reference below is the accounting as NumPy states it (np.bincount adds a slot's rows in order from 0.0,
np.maximum.at keeps the highest value, np.sum is NumPy's pairwise sum, np.argmax the first maximum): the
kernel must reproduce it exactly, or every estimate's last digits would move (``estimate --json`` prints
them in full).
"""
import numpy as np
import pytest

from gcodeplan.errors import GcodeError
from gcodeplan.report.summary import TimeSummary
from gcodeplan.schema import (FLAG_RAPID, KIND_DWELL, KIND_NAMES, KIND_PRINT, KIND_WAIT, LIMIT_NAMES, MOVE_DTYPE,
                              PLAN_DTYPE)


def _bincount_add(acc, idx, w):
    if idx.size == 0:
        return acc
    add = np.bincount(idx, weights=w)
    if add.size > acc.size:
        acc = np.concatenate([acc, np.zeros(add.size - acc.size)])
    acc[: add.size] += add
    return acc


def _max_at(acc, idx, v):
    if idx.size == 0:
        return acc
    top = int(idx.max()) + 1
    if top > acc.size:
        acc = np.concatenate([acc, np.zeros(top - acc.size)])
    with np.errstate(invalid="ignore"):      # a NaN peak is part of what is checked
        np.maximum.at(acc, idx, v)
    return acc


class NumpyTotals:
    """The totals of TimeSummary written with NumPy array operations, chunk by chunk."""

    def __init__(self):
        self.end_t = 0.0
        self.by_kind = np.zeros(len(KIND_NAMES))
        self.by_limit = np.zeros(len(LIMIT_NAMES))
        self.rapid_t = self.accel_t = self.cruise_t = self.decel_t = self.blend_t = 0.0
        self.by_layer, self.by_feature, self.by_object = np.zeros(1), np.zeros(1), np.zeros(1)
        self.fil_feature, self.ptime_feature, self.peak_feature = np.zeros(1), np.zeros(1), np.zeros(1)
        self.fil_layer, self.ptime_layer, self.peak_layer = np.zeros(1), np.zeros(1), np.zeros(1)
        self.peak_v, self.peak_v_line, self.stops = 0.0, 0, 0

    def add(self, moves, plan):
        dur = plan["duration"]
        end_max = float((plan["t_start"] + dur).max())
        self.end_t = end_max if not end_max <= self.end_t else self.end_t
        kind = moves["kind"].astype(np.intp)
        self.by_kind += np.bincount(kind, weights=dur, minlength=len(KIND_NAMES))[: len(KIND_NAMES)]
        self.by_limit += np.bincount(plan["limit"].astype(np.intp), weights=dur,
                                     minlength=len(LIMIT_NAMES))[: len(LIMIT_NAMES)]
        self.rapid_t += float(dur[(moves["flags"] & FLAG_RAPID) != 0].sum())
        self.accel_t += float(plan["accel_t"].sum())
        self.cruise_t += float(plan["cruise_t"].sum())
        self.decel_t += float(plan["decel_t"].sum())
        motion = (moves["kind"] != KIND_DWELL) & (moves["kind"] != KIND_WAIT)
        blend = np.where(motion, dur - (plan["accel_t"] + plan["cruise_t"] + plan["decel_t"]), 0.0)
        self.blend_t += float(blend[blend > 1e-9 * dur].sum())
        slot = {k: np.maximum(moves[k], -1).astype(np.intp) + 1 for k in ("layer", "feature", "object")}
        self.by_layer = _bincount_add(self.by_layer, slot["layer"], dur)
        self.by_feature = _bincount_add(self.by_feature, slot["feature"], dur)
        self.by_object = _bincount_add(self.by_object, slot["object"], dur)
        pr = moves["kind"] == KIND_PRINT
        fil = moves["e1"][pr] - moves["e0"][pr]
        move_d = moves["move_d"][pr]
        peak = np.divide(plan["cruise_v"][pr] * fil, move_d, out=np.zeros(len(fil)), where=move_d > 0.0)
        for key, fil_acc, t_acc, pk_acc in (("feature", "fil_feature", "ptime_feature", "peak_feature"),
                                            ("layer", "fil_layer", "ptime_layer", "peak_layer")):
            setattr(self, fil_acc, _bincount_add(getattr(self, fil_acc), slot[key][pr], fil))
            setattr(self, t_acc, _bincount_add(getattr(self, t_acc), slot[key][pr], dur[pr]))
            setattr(self, pk_acc, _max_at(getattr(self, pk_acc), slot[key][pr], peak))
        i = int(np.argmax(plan["cruise_v"]))
        if plan["cruise_v"][i] > self.peak_v:
            self.peak_v, self.peak_v_line = float(plan["cruise_v"][i]), int(moves["line"][i])
        self.stops += int(np.count_nonzero(motion & (plan["end_v"] == 0.0)))


def _random_chunk(rng, n, t0, line0):
    moves = np.zeros(n, MOVE_DTYPE)
    plan = np.zeros(n, PLAN_DTYPE)
    moves["line"] = line0 + np.arange(n)
    moves["kind"] = rng.choice([0, 1, 1, 1, 2, 3, 4], n)
    moves["flags"] = rng.choice([0, 0, FLAG_RAPID, 4], n)
    moves["layer"] = np.sort(rng.integers(-1, 40, n))
    moves["feature"] = rng.integers(-1, 9, n)
    moves["object"] = rng.choice([-1, -1, 0, 1, 3], n)
    moves["e0"] = rng.uniform(0, 100, n)
    moves["e1"] = moves["e0"] + rng.uniform(0, 0.3, n)
    moves["move_d"] = np.where(rng.random(n) < 0.05, 0.0, rng.uniform(0.0, 50.0, n))
    a, c, d = (rng.exponential(0.01, n) * (rng.random(n) < 0.8) for _ in range(3))
    plan["accel_t"], plan["cruise_t"], plan["decel_t"] = a, c, d
    # most rows add their phases exactly; some carry a blend part on top (planner/blend.py)
    plan["duration"] = a + c + d + np.where(rng.random(n) < 0.2, rng.exponential(0.002, n), 0.0)
    plan["t_start"] = t0 + np.concatenate([[0.0], np.cumsum(plan["duration"])[:-1]])
    plan["cruise_v"] = rng.choice([0.0, 50.0, 120.0, 300.0], n) + rng.uniform(0, 1, n)
    plan["end_v"] = np.where(rng.random(n) < 0.3, 0.0, rng.uniform(0, 100, n))
    plan["limit"] = rng.integers(0, len(LIMIT_NAMES), n)
    return moves, plan


FIELDS = ("end_t", "by_kind", "by_limit", "rapid_t", "accel_t", "cruise_t", "decel_t", "blend_t", "by_layer",
          "by_feature", "by_object", "fil_feature", "ptime_feature", "peak_feature", "fil_layer", "ptime_layer",
          "peak_layer", "peak_v", "peak_v_line", "stops")


@pytest.mark.parametrize("seed", range(6))
def test_kernel_totals_are_bit_identical_to_numpy(seed):
    rng = np.random.default_rng(seed)
    s, ref = TimeSummary(), NumpyTotals()
    t, line = 0.0, 1
    # chunk lengths around NumPy's pairwise-sum block (128) and the pipeline's batch (8192 + a few pending rows)
    for n in (1, 7, 8, 129, 1000, 8197, 3):
        moves, plan = _random_chunk(rng, n, t, line)
        t, line = float(plan["t_start"][-1] + plan["duration"][-1]), line + n
        s.add(moves, plan)
        ref.add(moves, plan)
    assert s.blend_t > 0 and s.rapid_t > 0 and s.stops > 0       # every total was exercised
    for name in FIELDS:
        got, want = np.asarray(getattr(s, name)), np.asarray(getattr(ref, name))
        assert got.shape == want.shape, name
        assert got.tobytes() == want.tobytes(), name


def test_a_nan_speed_is_the_peak_as_numpy_argmax_and_maximum_make_it():
    moves, plan = _random_chunk(np.random.default_rng(7), 50, 0.0, 1)
    moves["kind"] = KIND_PRINT
    moves["move_d"] = 1.0
    plan["cruise_v"][[10, 20]] = np.nan
    s, ref = TimeSummary(), NumpyTotals()
    s.add(moves, plan)
    ref.add(moves, plan)
    assert s.peak_v == ref.peak_v == 0.0 and s.peak_v_line == ref.peak_v_line == 0   # NaN > peak is False
    assert np.isnan(s.peak_layer).tobytes() == np.isnan(ref.peak_layer).tobytes()
    assert np.isnan(s.peak_feature).any()


def test_rows_outside_any_layer_feature_or_object_go_to_slot_zero_and_grow_nothing():
    moves, plan = _random_chunk(np.random.default_rng(3), 20, 0.0, 1)
    moves["layer"] = moves["feature"] = moves["object"] = -5
    s = TimeSummary()
    s.add(moves, plan)
    total = float(np.bincount(np.zeros(20, np.intp), weights=plan["duration"])[0])
    assert s.by_layer.tolist() == s.by_feature.tolist() == s.by_object.tolist() == [total]


def test_an_absurd_total_names_the_first_line_past_the_limit():
    moves, plan = _random_chunk(np.random.default_rng(5), 10, 0.0, 100)
    plan["duration"][6] = 1e9
    plan["t_start"][7:] += 1e9
    with pytest.raises(GcodeError, match="more than eleven years") as err:
        TimeSummary().add(moves, plan)
    assert err.value.line == 106
