"""Checks of the planner tests' helpers in conftest.py (MOVE rows from points, random programs)."""
from __future__ import annotations

import numpy as np

from gcodeplan.schema import (KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, MOVE_DTYPE)


from conftest import moves_from_points, random_program  # noqa: F401


def test_moves_from_points_kinds_and_lengths():
    mv = moves_from_points([(0, 0, 0, 0), (3, 4, 0, 1), (3, 4, 0, 0), (0, 0, 0, 0)])
    assert list(mv["kind"]) == [KIND_PRINT, KIND_EXTRUDE_ONLY, KIND_TRAVEL]
    assert list(mv["move_d"]) == [5.0, 1.0, 5.0]


