"""Time accounting over a plan, chunk by chunk.

``TimeSummary.add(moves, plan)`` folds one planned chunk into running totals:
one numba pass over the chunk's rows (:func:`chunk_totals_kernel`) gives the
chunk's own per-slot sums, which are then added to the running arrays, so a
1.8-million-move file costs one kernel call and a few array operations per chunk
and nothing per move in Python.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._jit import njit
from ..errors import GcodeError
from ..schema import (
    FLAG_RAPID,
    KIND_DWELL,
    KIND_EXTRUDE_ONLY,
    KIND_NAMES,
    KIND_PRINT,
    KIND_TRAVEL,
    KIND_WAIT,
    LIMIT_NAMES,
    MOVE_DTYPE,
    PLAN_DTYPE,
)


N_KINDS = len(KIND_NAMES)
N_LIMITS = len(LIMIT_NAMES)


# error_model="numpy": no zero-division checks in the loop (the one division is guarded)
@njit(cache=True, error_model="numpy")
def chunk_totals_kernel(moves, plan):
    """One pass over a planned chunk (MOVE and PLAN rows, aligned): the chunk's own totals.

    Returns (end_s, kind_s, limit_s, layer_s, feature_s, object_s, fil_feature_mm, print_feature_s,
    peak_feature_mm_s, fil_layer_mm, print_layer_s, peak_layer_mm_s, rapid_s, n_rapid, blend_s, n_blend,
    stops, peak_row):

    * ``end_s``: the latest t_start + duration (NaN when one is NaN: a time the planner could not compute
      must not vanish, found by tools/fuzz.py);
    * per-slot sums of the duration (s), slot = kind, limit, layer + 1, feature + 1, object + 1 (-1 and
      below go to slot 0), each array as long as the highest slot used + 1. Rows are added in order from
      0.0, exactly as ``np.bincount`` adds them, so the totals do not change in the last bit;
    * the same per feature / layer slot over the printing rows only: filament pushed (mm), their time (s)
      and the highest filament speed at cruise (mm/s, cruise_v · ΔE / path length, 0 for no path);
    * the durations (s) of the G0 rows and the blend halves (duration minus the phases, where above
      rounding) packed at the front of ``rapid_s`` / ``blend_s``: the caller sums them with ``np.sum``,
      whose pairwise order the totals have always had;
    * ``stops``: motion rows ending at rest; ``peak_row``: the row of the highest cruise speed (the first
      one, or the first NaN, as ``np.argmax`` picks it).
    """
    n = moves.shape[0]
    top_layer = top_feature = top_object = 0
    top_print_layer = top_print_feature = -1
    for i in range(n):
        mv = moves[i]
        layer_slot = max(mv.layer, -1) + 1
        feature_slot = max(mv.feature, -1) + 1
        top_layer = max(top_layer, layer_slot)
        top_feature = max(top_feature, feature_slot)
        top_object = max(top_object, max(mv.object, -1) + 1)
        if mv.kind == KIND_PRINT:
            top_print_layer = max(top_print_layer, layer_slot)
            top_print_feature = max(top_print_feature, feature_slot)
    kind_s = np.zeros(N_KINDS)
    limit_s = np.zeros(N_LIMITS)
    layer_s = np.zeros(top_layer + 1)
    feature_s = np.zeros(top_feature + 1)
    object_s = np.zeros(top_object + 1)
    fil_feature = np.zeros(top_print_feature + 1)
    print_feature = np.zeros(top_print_feature + 1)
    peak_feature = np.zeros(top_print_feature + 1)
    fil_layer = np.zeros(top_print_layer + 1)
    print_layer = np.zeros(top_print_layer + 1)
    peak_layer = np.zeros(top_print_layer + 1)
    rapid_s = np.empty(n)
    blend_s = np.empty(n)
    n_rapid = n_blend = stops = 0
    end_s = -np.inf
    peak_row = 0
    peak_v = plan[0].cruise_v if n else 0.0
    for i in range(n):
        mv = moves[i]
        pl = plan[i]
        dur = pl.duration
        end = pl.t_start + dur
        if end > end_s or end != end:
            if end_s == end_s:          # the first NaN stays
                end_s = end
        if mv.kind < N_KINDS:
            kind_s[mv.kind] += dur
        if pl.limit < N_LIMITS:
            limit_s[pl.limit] += dur
        if mv.flags & FLAG_RAPID:
            rapid_s[n_rapid] = dur
            n_rapid += 1
        motion = mv.kind != KIND_DWELL and mv.kind != KIND_WAIT
        # duration = τ_in + accel_t + cruise_t + decel_t + τ_out for blends (planner/blend.py); the other
        # planners add their phases exactly up to rounding, which must not show as blending
        blend = dur - (pl.accel_t + pl.cruise_t + pl.decel_t) if motion else 0.0
        if blend > 1e-9 * dur:
            blend_s[n_blend] = blend
            n_blend += 1
        if motion and pl.end_v == 0.0:
            stops += 1
        layer_slot = max(mv.layer, -1) + 1
        feature_slot = max(mv.feature, -1) + 1
        layer_s[layer_slot] += dur
        feature_s[feature_slot] += dur
        object_s[max(mv.object, -1) + 1] += dur
        if mv.kind == KIND_PRINT:
            fil = mv.e1 - mv.e0
            peak = (pl.cruise_v * fil) / mv.move_d if mv.move_d > 0.0 else 0.0
            fil_feature[feature_slot] += fil
            print_feature[feature_slot] += dur
            fil_layer[layer_slot] += fil
            print_layer[layer_slot] += dur
            # np.maximum's rule: a NaN wins
            if peak > peak_feature[feature_slot] or peak != peak:
                peak_feature[feature_slot] = peak
            if peak > peak_layer[layer_slot] or peak != peak:
                peak_layer[layer_slot] = peak
        cv = pl.cruise_v
        if peak_v == peak_v and (cv > peak_v or cv != cv):
            peak_row = i
            peak_v = cv
    return (end_s, kind_s, limit_s, layer_s, feature_s, object_s, fil_feature, print_feature, peak_feature,
            fil_layer, print_layer, peak_layer, rapid_s, n_rapid, blend_s, n_blend, stops, peak_row)


def _grow_add(acc: np.ndarray, part: np.ndarray) -> np.ndarray:
    """acc[:part.size] += part, growing acc with zeros as needed."""
    if part.size > acc.size:
        acc = np.concatenate([acc, np.zeros(part.size - acc.size)])
    acc[: part.size] += part
    return acc


def _grow_max(acc: np.ndarray, part: np.ndarray) -> np.ndarray:
    """acc[:part.size] = max(acc, part) (a NaN wins), growing acc with zeros as needed."""
    if part.size > acc.size:
        acc = np.concatenate([acc, np.zeros(part.size - acc.size)])
    np.maximum(acc[: part.size], part, out=acc[: part.size])
    return acc


def _rows(arr: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``arr`` as contiguous rows of ``dtype`` (the kernel's one specialisation): no copy for the rows the
    pipeline makes; rows of another layout are copied field by field (an absent ``object`` is -1: none)."""
    if arr.dtype == dtype:
        return np.ascontiguousarray(arr)
    out = np.zeros(len(arr), dtype)
    if "object" in dtype.names:
        out["object"] = -1
    for name in dtype.names:
        if name in arr.dtype.names:
            out[name] = arr[name]
    return out


# s: a planned total above 1e5 h (over eleven years; no print or cut runs a year) is an error naming the
# line where it is crossed, never printed as an estimate (a mistyped F0.00001, a huge move at 1 mm/min)
MAX_TOTAL_S = 1e5 * 3600.0


@dataclass
class TimeSummary:
    """Running totals of a plan. All times in seconds."""

    end_t: float = 0.0                 # end of the last planned move (= total time)
    moves_planned: int = 0
    by_kind: np.ndarray = field(default_factory=lambda: np.zeros(len(KIND_NAMES)))
    by_limit: np.ndarray = field(default_factory=lambda: np.zeros(len(LIMIT_NAMES)))
    accel_t: float = 0.0
    cruise_t: float = 0.0
    decel_t: float = 0.0
    # blend mode: the corner blends' halves a PLAN row holds besides its straight part's phases
    blend_t: float = 0.0
    # index = layer + 1 (slot 0 holds moves before the first layer change)
    by_layer: np.ndarray = field(default_factory=lambda: np.zeros(1))
    # index = feature + 1 (slot 0 holds moves with no feature tag)
    by_feature: np.ndarray = field(default_factory=lambda: np.zeros(1))
    # index = object + 1 (slot 0 holds time outside any object)
    by_object: np.ndarray = field(default_factory=lambda: np.zeros(1))
    # flow (docs in flows()): filament mm pushed by printing moves, their time (s), and the highest
    # filament speed at cruise (mm/s), per feature slot and per layer slot (same slots as above)
    fil_feature: np.ndarray = field(default_factory=lambda: np.zeros(1))
    ptime_feature: np.ndarray = field(default_factory=lambda: np.zeros(1))
    peak_feature: np.ndarray = field(default_factory=lambda: np.zeros(1))
    fil_layer: np.ndarray = field(default_factory=lambda: np.zeros(1))
    ptime_layer: np.ndarray = field(default_factory=lambda: np.zeros(1))
    peak_layer: np.ndarray = field(default_factory=lambda: np.zeros(1))
    rapid_t: float = 0.0               # G0 moves (CNC: rapids; printers: Cura's G0 travels)
    peak_v: float = 0.0                # mm/s highest planned cruise speed
    peak_v_line: int = 0
    stops: int = 0                     # moves ending at rest
    line_end_t_last: tuple[int, float] = (0, 0.0)

    def add(self, moves: np.ndarray, plan: np.ndarray) -> None:
        """Fold one planned chunk (MOVE rows and their PLAN rows, in program order) into the totals."""
        if moves.size == 0:
            return
        if len(plan) != len(moves):     # the kernel reads both row by row
            raise ValueError(f"TimeSummary.add: {len(moves)} MOVE rows but {len(plan)} PLAN rows")
        self.moves_planned += moves.size
        (end_max, kind_s, limit_s, layer_s, feature_s, object_s, fil_feature, print_feature, peak_feature,
         fil_layer, print_layer, peak_layer, rapid_s, n_rapid, blend_s, n_blend, stops,
         peak_row) = chunk_totals_kernel(_rows(moves, MOVE_DTYPE), _rows(plan, PLAN_DTYPE))
        # not max(): a NaN time (one the planner could not compute) must not vanish (found by tools/fuzz.py)
        self.end_t = end_max if not end_max <= self.end_t else self.end_t
        if not self.end_t <= MAX_TOTAL_S:
            end = plan["t_start"] + plan["duration"]
            i = int(np.argmax(~(end <= MAX_TOTAL_S)))
            if self.end_t != self.end_t:
                raise GcodeError("the planned time is not a number by here: an absurd feed rate, acceleration or "
                                 "distance?", None, int(moves["line"][i]))
            raise GcodeError(f"the program would run {self.end_t / 3600:.3g} h by here (over {MAX_TOTAL_S / 3600:g} h,"
                             f" more than eleven years): an absurd feed rate or distance?", None,
                             int(moves["line"][i]))
        self.by_kind += kind_s
        self.by_limit += limit_s
        # np.sum, not a running sum: these totals have always been NumPy's pairwise sums per chunk
        self.rapid_t += float(rapid_s[:n_rapid].sum())
        self.accel_t += float(plan["accel_t"].sum())
        self.cruise_t += float(plan["cruise_t"].sum())
        self.decel_t += float(plan["decel_t"].sum())
        self.blend_t += float(blend_s[:n_blend].sum())
        self.by_layer = _grow_add(self.by_layer, layer_s)
        self.by_feature = _grow_add(self.by_feature, feature_s)
        self.by_object = _grow_add(self.by_object, object_s)
        self.fil_feature = _grow_add(self.fil_feature, fil_feature)
        self.ptime_feature = _grow_add(self.ptime_feature, print_feature)
        self.peak_feature = _grow_max(self.peak_feature, peak_feature)
        self.fil_layer = _grow_add(self.fil_layer, fil_layer)
        self.ptime_layer = _grow_add(self.ptime_layer, print_layer)
        self.peak_layer = _grow_max(self.peak_layer, peak_layer)
        cruise_v = plan["cruise_v"][peak_row]
        if cruise_v > self.peak_v:
            self.peak_v = float(cruise_v)
            self.peak_v_line = int(moves["line"][peak_row])
        self.stops += int(stops)

    # ------------------------------------------------------------------ views
    def objects(self, names: list[str]) -> tuple[dict[str, float], float]:
        """({object name: s}, s outside any object): every row's time goes to its object; the two
        parts sum to the total. Objects labelled but never reached show 0."""
        out = {n: 0.0 for n in names}
        outside = float(self.by_object[0])
        for slot in range(1, self.by_object.size):
            if slot - 1 < len(names):
                out[names[slot - 1]] += float(self.by_object[slot])
            else:                       # rows built without an object table (np.zeros): none
                outside += float(self.by_object[slot])
        return out, outside

    def flows(self, feature_names: list[str], layer_z: list[float], filament_diameter_mm: float) -> dict:
        """Volumetric flow (mm³/s) of the printing moves (XYZ motion with E increasing), per feature and
        per layer: ``average`` = filament volume pushed ÷ the planned time of those moves (acceleration and
        deceleration included); ``peak`` = the highest filament speed at a move's cruise speed
        (cruise_v · ΔE / path length) times the filament's cross-section π·d²/4."""
        area = np.pi * filament_diameter_mm ** 2 / 4.0

        def rows(fil, t, peak):
            for slot in range(fil.size):
                if t[slot] > 0 or fil[slot] > 0:
                    avg = float(fil[slot] * area / t[slot]) if t[slot] > 0 else 0.0
                    yield slot, {"average_mm3_s": avg, "peak_mm3_s": float(peak[slot] * area),
                                 "filament_mm": float(fil[slot]), "print_time_s": float(t[slot])}

        feats = {}
        for slot, d in rows(self.fil_feature, self.ptime_feature, self.peak_feature):
            name = "(untagged)" if slot == 0 else (feature_names[slot - 1] if slot - 1 < len(feature_names)
                                                   else f"feature {slot - 1}")
            feats[name] = d
        layers = []
        for slot, d in rows(self.fil_layer, self.ptime_layer, self.peak_layer):
            idx = slot - 1
            z = float(layer_z[idx]) if 0 <= idx < len(layer_z) else None
            layers.append({"index": idx, "z": z, **d})
        return {"filament_diameter_mm": filament_diameter_mm, "features": feats, "layers": layers}

    @property
    def total_time_s(self) -> float:
        return self.end_t

    @property
    def waits_s(self) -> float:
        return float(self.by_kind[KIND_WAIT])

    @property
    def dwell_s(self) -> float:
        return float(self.by_kind[KIND_DWELL])

    @property
    def print_time_s(self) -> float:
        return float(self.by_kind[KIND_PRINT])

    @property
    def travel_time_s(self) -> float:
        return float(self.by_kind[KIND_TRAVEL])

    @property
    def extrude_only_time_s(self) -> float:
        return float(self.by_kind[KIND_EXTRUDE_ONLY])

    @property
    def before_first_layer_s(self) -> float:
        """Time of the moves before the first layer change (start G-code, purge line): not in layers()."""
        return float(self.by_layer[0])

    def layers(self, layer_z: list[float]) -> list[dict]:
        out = []
        for slot in range(1, self.by_layer.size):
            idx = slot - 1
            z = float(layer_z[idx]) if idx < len(layer_z) else None
            out.append({"index": idx, "z": z, "time_s": float(self.by_layer[slot])})
        return out

    def features(self, names: list[str]) -> dict[str, float]:
        out: dict[str, float] = {}
        if self.by_feature[0] > 0:
            out["(untagged)"] = float(self.by_feature[0])
        for slot in range(1, self.by_feature.size):
            name = names[slot - 1] if slot - 1 < len(names) else f"feature {slot - 1}"
            if self.by_feature[slot] > 0:
                out[name] = out.get(name, 0.0) + float(self.by_feature[slot])
        return out

    def limits(self) -> dict[str, float]:
        return {LIMIT_NAMES[i]: float(t) for i, t in enumerate(self.by_limit) if t > 0}


def hms(seconds: float) -> str:
    """Seconds as h:mm:ss (rounded to the second), the way slicers print times."""
    if not np.isfinite(seconds):
        return str(seconds)
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"
