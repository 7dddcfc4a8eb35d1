"""The estimate of one program: time accounting, JSON and text forms.

:class:`Estimate` is what :func:`gcodeplan.estimate` returns and what ``gcodeplan estimate`` prints.
Every breakdown in :meth:`Estimate.to_json` sums to ``total_time_s``.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from .summary import TimeSummary, hms


@dataclass
class Estimate:
    """The planned time of one program and its breakdowns (all times in s).

    ``path``: the source's name; ``parse``: the parser's summary (counts, distances, filament);
    ``time``: the running totals (:class:`~gcodeplan.report.summary.TimeSummary`); ``layer_z`` (mm) and
    ``features`` name the layers and feature tags; ``policy`` and ``machine_name`` say how it was planned.
    """
    path: str
    parse: object          # ParseSummary
    time: TimeSummary
    layer_z: list
    features: list
    policy: str
    machine_name: str
    line_ends: tuple = field(default=(None, None), repr=False)   # (line, end_time_s) arrays
    objects: list = field(default_factory=list)          # object names (MOVE.object indexes them)
    wait_time_s: dict = field(default_factory=dict)      # s of modelled waits by name ([time] of the machine)
    filament_diameter_mm: float = 1.75                   # for the volumetric flow
    firmware: str = ""                                   # the firmware model that planned it ("" = the policy)

    @property
    def total_time_s(self) -> float:
        """Planned time of the whole program (s), from the first move's start to the last move's end."""
        return self.time.total_time_s

    def line_times(self) -> tuple[np.ndarray, np.ndarray]:
        """(line int64, end_time_s float64): when the last move or dwell each source line made ends
        (s from the first move's start), one row per such line, lines increasing. The format of
        Klipper's per-line reference CSVs (``source_line,end_time_s``)."""
        if self.line_ends[0] is None:
            from ..errors import GcodeplanError

            raise GcodeplanError("per-line times were not kept (estimate(..., line_times=False))", self.path)
        return self.line_ends

    def to_text(self) -> str:
        """The human-readable summary ``gcodeplan estimate`` prints."""
        import io

        buf = io.StringIO()
        print_text(self, buf)
        return buf.getvalue()

    def to_json(self) -> dict:
        """The dict ``gcodeplan estimate --json`` prints (see the README for its keys). ``firmware``: the firmware
        model that planned ("" = the policy alone), ``firmware_version``: the firmware build it reproduces."""
        from ..machine import firmware_version

        d = dict(self.parse.to_json())
        t = self.time
        d.update(
            file=self.path,
            machine=self.machine_name,
            policy=self.policy,
            firmware=self.firmware,
            firmware_version=firmware_version(self.firmware),
            total_time_s=t.total_time_s,
            total_time_hms=hms(t.total_time_s),
            moves=self.parse.moves,
            print_time_s=t.print_time_s,
            travel_time_s=t.travel_time_s,
            extrude_only_time_s=t.extrude_only_time_s,
            rapid_time_s=t.rapid_t,
            dwell_s=t.dwell_s,
            waits_s=t.waits_s,
            accelerating_s=t.accel_t,
            cruising_s=t.cruise_t,
            decelerating_s=t.decel_t,
            blending_s=t.blend_t,
            limits_s=t.limits(),
            peak_speed_mm_s=t.peak_v,
            full_stops=t.stops,
            before_first_layer_s=t.before_first_layer_s,
            layers=t.layers(self.layer_z),
            features=t.features(self.features),
        )
        objects, outside = t.objects(self.objects)
        d.update(objects=objects, outside_objects_s=outside, waits_by_name_s=dict(self.wait_time_s),
                 flow=t.flows(self.features, self.layer_z, self.filament_diameter_mm))
        return d


def planned_by_text(est: Estimate) -> str:
    """How ``est`` was planned, as the summary names it: the firmware model and the firmware version it
    reproduces (``firmware marlin-2.1.2 (Marlin 2.1.2.4)``), or the junction policy when that planned alone."""
    from ..machine import firmware_version

    if not est.firmware:
        return f"policy {est.policy}"
    version = firmware_version(est.firmware)
    return f"firmware {est.firmware}" + (f" ({version})" if version else "")


def print_text(est: Estimate, out=None) -> None:
    """The summary ``gcodeplan estimate`` prints (:meth:`Estimate.to_text`), section by section."""
    w = (out or sys.stdout).write
    dialect = _print_header(est, w)
    _print_times(est, w)
    _print_shares(est, w)
    _print_flow(est, w)
    _print_layers(est, w)
    _print_notes(est, w, dialect)


def _print_header(est: Estimate, w) -> dict | None:
    """File, machine, what planned it, the G-code dialect; returns the dialect note (its warning is said here)."""
    w(f"{est.path}\n")
    w(f"  machine {est.machine_name}, {planned_by_text(est)}\n")
    dialect = getattr(est.parse, "dialect", None)
    if dialect:
        from ..gcode.dialect import note_text

        w(f"  dialect: {note_text(dialect)}\n")
        if dialect.get("warning"):
            w(f"  warning: {dialect['warning']}\n")
    return dialect


def _print_times(est: Estimate, w) -> None:
    """The totals: planned, naive and the slicer's; by kind of move; by speed phase; moves, stops and boxes."""
    t, s = est.time, est.parse
    w(f"  total time      {hms(t.total_time_s):>10}  ({t.total_time_s:.3f} s)\n")
    naive = s.naive_time_s
    w(f"  naive time      {hms(naive):>10}  ({naive:.3f} s, distance / feed rate, for contrast)\n")
    slicer = getattr(s, "slicer_estimate_s", None)
    if slicer:
        w(f"  slicer's own    {hms(slicer):>10}  ({slicer:.0f} s)\n")
    waits = getattr(s, "waits", None) or {}
    timed = {k: v for k, v in waits.items() if k in ("heat", "homing", "M109", "M190", "G28")}
    note = ""
    if waits and t.waits_s == 0:
        what = ", ".join(f"{k}×{v}" for k, v in sorted(waits.items()))
        note = f" ({what}: no time modelled" + ("; set [time] in the machine file)" if timed else ")")
    if t.print_time_s == 0 and t.extrude_only_time_s == 0:   # no extrusion: a mill, laser or plotter
        w(f"  feed moves {hms(t.travel_time_s - t.rapid_t)}, rapids (G0) {hms(t.rapid_t)}, "
          f"dwell {hms(t.dwell_s)}, waits {hms(t.waits_s)}{note}\n")
    else:
        w(f"  print {hms(t.print_time_s)}, travel {hms(t.travel_time_s)}, extrude-only {hms(t.extrude_only_time_s)}, "
          f"dwell {hms(t.dwell_s)}, waits {hms(t.waits_s)}{note}\n")
    motion = max(t.accel_t + t.cruise_t + t.decel_t + t.blend_t, 1e-300)
    blending = f", blending {100 * t.blend_t / motion:.1f} %" if t.blend_t > 0 else ""
    w(f"  accelerating {100 * t.accel_t / motion:.1f} %, cruising {100 * t.cruise_t / motion:.1f} %, "
      f"decelerating {100 * t.decel_t / motion:.1f} %{blending}\n")
    w(f"  moves {s.moves}, full stops {t.stops}, peak speed {t.peak_v:.1f} mm/s (line {t.peak_v_line})\n")
    from ..gcode.summary import box_text, capped_text, clamped_text

    for what, b in (("print", getattr(s, "print_bounds_mm", None)), ("travel", getattr(s, "travel_bounds_mm", None))):
        if b:
            w(f"  {what + ' box':<16}{box_text(b)}\n")
    if getattr(s, "speed_capped_moves", 0):
        w(f"  {capped_text(s.speed_capped_moves, s.speed_capped_first_line)}\n")
    if getattr(s, "soft_clamped_moves", 0):
        w(f"  {clamped_text(s.soft_clamped_moves, s.soft_clamped_first_line)}\n")


def _print_shares(est: Estimate, w) -> None:
    """Where the time went: what limited the speed, per feature, per object, the named waits."""
    t = est.time
    lim = t.limits()
    if lim:
        tot = sum(lim.values())
        w("  what limited the speed (share of time):\n")
        for name, sec in sorted(lim.items(), key=lambda kv: -kv[1]):
            w(f"    {name:<14} {hms(sec):>10}  {100 * sec / tot:5.1f} %\n")
    feats = t.features(est.features)
    if feats:
        w("  time per feature:\n")
        for name, sec in sorted(feats.items(), key=lambda kv: -kv[1]):
            w(f"    {name:<28} {hms(sec):>10}  {100 * sec / max(t.total_time_s, 1e-300):5.1f} %\n")
    objects, outside = t.objects(getattr(est, "objects", []))
    if objects:
        w("  time per object:\n")
        total = max(t.total_time_s, 1e-300)
        for name, sec in list(objects.items()) + [("(outside any object)", outside)]:
            w(f"    {name[:40]:<40} {hms(sec):>10}  {100 * sec / total:5.1f} %\n")
    named = getattr(est, "wait_time_s", {}) or {}
    if named:
        w("  waits by name: " + ", ".join(f"{k} {hms(v)}" for k, v in sorted(named.items())) + "\n")


def _print_flow(est: Estimate, w) -> None:
    """The volumetric flow of the printing moves per feature, and the layers of highest peak and average."""
    flow = est.time.flows(est.features, est.layer_z, getattr(est, "filament_diameter_mm", 1.75))
    if not flow["features"]:
        return
    w(f"  volumetric flow of printing moves (mm³/s; filament {flow['filament_diameter_mm']:g} mm; "
      f"peak = at cruise speed):\n")
    for name, f in sorted(flow["features"].items(), key=lambda kv: -kv[1]["print_time_s"]):
        w(f"    {name:<28} average {f['average_mm3_s']:7.2f}   peak {f['peak_mm3_s']:7.2f}\n")
    in_layers = [L for L in flow["layers"] if L["index"] >= 0]     # not the start G-code's purge line
    if in_layers:
        top = max(in_layers, key=lambda L: L["peak_mm3_s"])
        busy = max(in_layers, key=lambda L: L["average_mm3_s"])
        w(f"    layers: highest peak {top['peak_mm3_s']:.2f} (layer {top['index']}), highest average "
          f"{busy['average_mm3_s']:.2f} (layer {busy['index']})\n")


def _print_layers(est: Estimate, w) -> None:
    """The layer count, the slowest and the mean layer; each layer's time when there are 40 or fewer."""
    t = est.time
    layers = t.layers(est.layer_z)
    if not layers:
        return
    w(f"  layers: {len(layers)}")
    if t.before_first_layer_s > 0:
        w(f" (+ {hms(t.before_first_layer_s)} before the first)")
    times = [L["time_s"] for L in layers]
    slow = max(range(len(times)), key=times.__getitem__)
    w(f", slowest #{slow} ({hms(times[slow])}), mean {hms(sum(times) / len(times))}\n")
    if len(layers) <= 40:
        for L in layers:
            z = "" if L["z"] is None else f" z={L['z']:.3f}"
            w(f"    layer {L['index']:>4}{z:<12} {hms(L['time_s']):>10}\n")


def _print_notes(est: Estimate, w, dialect: dict | None) -> None:
    """What was not modelled (counted commands) and the reader's warnings."""
    s = est.parse
    unknown = getattr(s, "unknown_commands", {}) or {}
    if unknown:
        items = ", ".join(f"{k}×{v}" for k, v in sorted(unknown.items(), key=lambda kv: -kv[1])[:12])
        w(f"  not modelled (counted): {items}\n")
    # the reader's warnings (probe moves timed to their target, a G41 planned uncompensated, …): a user reading
    # only the text must see them too; the dialect's own warning is printed above
    said = dialect.get("warning") if dialect else None
    warns = [x for x in (getattr(s, "warnings", None) or []) if x != said]
    if warns:
        more = max(int(getattr(s, "warning_count", 0) or 0), len(warns)) - len(warns)
        for x in warns[:5]:
            w(f"  warning: {x}\n")
        if len(warns) > 5 or more > 0:
            w(f"  … {len(warns) - 5 + more if len(warns) > 5 else more} more warnings (--json lists them)\n")
