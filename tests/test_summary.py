"""TimeSummary folds planned chunks into totals: checked against sums worked by hand."""
import numpy as np

from gcodeplan.report.summary import TimeSummary, hms
from gcodeplan.schema import KIND_PRINT, KIND_TRAVEL, KIND_WAIT, LIMIT_FEED, LIMIT_JUNCTION, LIMIT_NONE, MOVE_DTYPE, PLAN_DTYPE


def _chunk(rows):
    moves = np.zeros(len(rows), MOVE_DTYPE)
    plan = np.zeros(len(rows), PLAN_DTYPE)
    t = 0.0
    for i, (kind, layer, feature, dur, limit, cruise) in enumerate(rows):
        moves[i]["kind"], moves[i]["layer"], moves[i]["feature"], moves[i]["line"] = kind, layer, feature, i + 1
        plan[i]["t_start"], plan[i]["duration"], plan[i]["limit"] = t, dur, limit
        plan[i]["cruise_t"], plan[i]["cruise_v"] = dur, cruise
        t += dur
    return moves, plan, t


def test_totals_by_layer_feature_kind_and_limit_over_two_chunks():
    m1, p1, t1 = _chunk([(KIND_TRAVEL, -1, -1, 1.0, LIMIT_FEED, 100.0), (KIND_PRINT, 0, 0, 2.0, LIMIT_JUNCTION, 40.0)])
    m2, p2, t2 = _chunk([(KIND_PRINT, 1, 1, 3.0, LIMIT_FEED, 60.0), (KIND_WAIT, 1, 1, 0.5, LIMIT_NONE, 0.0)])
    p2["t_start"] += t1
    s = TimeSummary()
    s.add(m1, p1)
    s.add(m2, p2)
    assert s.total_time_s == 6.5
    assert s.print_time_s == 5.0 and s.travel_time_s == 1.0 and s.waits_s == 0.5
    assert s.layers([0.2, 0.4]) == [{"index": 0, "z": 0.2, "time_s": 2.0}, {"index": 1, "z": 0.4, "time_s": 3.5}]
    assert s.features(["perimeter", "infill"]) == {"(untagged)": 1.0, "perimeter": 2.0, "infill": 3.5}
    assert s.limits() == {"feed": 4.0, "junction": 2.0, "none": 0.5}
    assert s.peak_v == 100.0 and s.peak_v_line == 1


def test_hms_rounds_to_the_second():
    assert hms(0) == "0:00:00"
    assert hms(3599.6) == "1:00:00"
    assert hms(69287.656) == "19:14:48"
