"""Time accounting over a plan, chunk by chunk.

``TimeSummary.add(moves, plan)`` folds one planned chunk into running totals
with vectorised NumPy (bincount), so a 1.8-million-move file costs a handful of
array operations per 64k-move chunk and nothing per move in Python.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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
)


def _grow_max(acc: np.ndarray, idx: np.ndarray, values: np.ndarray) -> np.ndarray:
    """acc[idx] = max(acc[idx], values), growing acc as needed (idx ≥ 0)."""
    if idx.size == 0:
        return acc
    top = int(idx.max()) + 1
    if top > acc.size:
        acc = np.concatenate([acc, np.zeros(top - acc.size)])
    np.maximum.at(acc, idx, values)
    return acc


def _grow_add(acc: np.ndarray, idx: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """acc[idx] += weights, growing acc as needed (idx ≥ 0)."""
    if idx.size == 0:
        return acc
    add = np.bincount(idx, weights=weights)
    if add.size > acc.size:
        acc = np.concatenate([acc, np.zeros(add.size - acc.size)])
    acc[: add.size] += add
    return acc


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
        if moves.size == 0:
            return
        dur = plan["duration"]
        self.moves_planned += moves.size
        end = plan["t_start"] + dur
        end_max = float(end.max())
        # not max(): a NaN time (one the planner could not compute) must not vanish (found by tools/fuzz.py)
        self.end_t = end_max if not end_max <= self.end_t else self.end_t
        if not self.end_t <= MAX_TOTAL_S:
            i = int(np.argmax(~(end <= MAX_TOTAL_S)))
            if self.end_t != self.end_t:
                raise GcodeError("the planned time is not a number by here: an absurd feed rate, acceleration or "
                                 "distance?", None, int(moves["line"][i]))
            raise GcodeError(f"the program would run {self.end_t / 3600:.3g} h by here (over {MAX_TOTAL_S / 3600:g} h,"
                             f" more than eleven years): an absurd feed rate or distance?", None,
                             int(moves["line"][i]))
        kind = moves["kind"].astype(np.intp)
        self.by_kind += np.bincount(kind, weights=dur, minlength=len(KIND_NAMES))[: len(KIND_NAMES)]
        self.by_limit += np.bincount(plan["limit"].astype(np.intp), weights=dur,
                                     minlength=len(LIMIT_NAMES))[: len(LIMIT_NAMES)]
        self.rapid_t += float(dur[(moves["flags"] & FLAG_RAPID) != 0].sum())
        phases_t = plan["accel_t"] + plan["cruise_t"] + plan["decel_t"]
        self.accel_t += float(plan["accel_t"].sum())
        self.cruise_t += float(plan["cruise_t"].sum())
        self.decel_t += float(plan["decel_t"].sum())
        kind = moves["kind"]
        motion = (kind != KIND_DWELL) & (kind != KIND_WAIT)
        # duration = τ_in + accel_t + cruise_t + decel_t + τ_out for blends (planner/blend.py); the other
        # planners add their phases exactly up to rounding, which must not show as blending
        blend = np.where(motion, dur - phases_t, 0.0)
        self.blend_t += float(blend[blend > 1e-9 * dur].sum())
        self.by_layer = _grow_add(self.by_layer, np.maximum(moves["layer"], -1).astype(np.intp) + 1, dur)
        self.by_feature = _grow_add(self.by_feature, np.maximum(moves["feature"], -1).astype(np.intp) + 1, dur)
        self._add_objects_and_flow(moves, plan, dur)
        i = int(np.argmax(plan["cruise_v"]))
        if plan["cruise_v"][i] > self.peak_v:
            self.peak_v = float(plan["cruise_v"][i])
            self.peak_v_line = int(moves["line"][i])
        self.stops += int(np.count_nonzero(motion & (plan["end_v"] == 0.0)))

    def _add_objects_and_flow(self, moves: np.ndarray, plan: np.ndarray, dur: np.ndarray) -> None:
        if "object" in moves.dtype.names:
            self.by_object = _grow_add(self.by_object, np.maximum(moves["object"], -1).astype(np.intp) + 1, dur)
        else:
            self.by_object[0] += float(dur.sum())
        pr = moves["kind"] == KIND_PRINT
        if not np.any(pr):
            return
        # the columns needed, not moves[pr] / plan[pr]: selecting whole structured rows copies ~200 bytes per
        # row (a third of the accounting time on a 50 MB file, tools/bench.py startup)
        fil = moves["e1"][pr] - moves["e0"][pr]
        duration = plan["duration"][pr]
        # filament speed at the move's cruise speed: E moves in proportion to the path (mm/s of filament)
        move_d = moves["move_d"][pr]
        peak = np.divide(plan["cruise_v"][pr] * fil, move_d, out=np.zeros(len(fil)), where=move_d > 0.0)
        for slot, fil_acc, t_acc, pk_acc in (
                (np.maximum(moves["feature"][pr], -1).astype(np.intp) + 1, "fil_feature", "ptime_feature",
                 "peak_feature"),
                (np.maximum(moves["layer"][pr], -1).astype(np.intp) + 1, "fil_layer", "ptime_layer", "peak_layer")):
            setattr(self, fil_acc, _grow_add(getattr(self, fil_acc), slot, fil))
            setattr(self, t_acc, _grow_add(getattr(self, t_acc), slot, duration))
            setattr(self, pk_acc, _grow_max(getattr(self, pk_acc), slot, peak))

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
