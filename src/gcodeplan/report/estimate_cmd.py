"""``gcodeplan estimate``: parse, plan, and account for the time of one or many files."""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass

from ..cli import add_machine_arguments
from ..errors import GcodeplanError, located
from ..machine import POLICIES
from .summary import TimeSummary, hms


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help="G-code file(s)")
    add_machine_arguments(p)
    p.add_argument("--policy", choices=POLICIES,
                   help="junction policy, overriding the machine's (klipper, junction-deviation, classic-jerk, "
                        "blend, exact-stop)")
    p.add_argument("--jerk", type=float, metavar="J",
                   help="plan jerk-limited S-curves with this path jerk limit (mm/s³) instead of trapezoids")
    p.add_argument("--json", action="store_true", help="print one JSON object (a list of them for many files)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="estimate many files in N parallel processes (default 1)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


@dataclass
class Estimate:
    path: str
    parse: object          # ParseSummary
    time: TimeSummary
    layer_z: list
    features: list
    policy: str
    machine_name: str

    def to_json(self) -> dict:
        d = dict(self.parse.to_json())
        t = self.time
        d.update(
            file=self.path,
            machine=self.machine_name,
            policy=self.policy,
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
        return d


def _progress(path: str, quiet: bool):
    """A bytes progress bar on stderr that only appears for runs longer than a second."""
    if quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=os.path.getsize(path), unit="B", unit_scale=True, delay=1.0,
                desc=os.path.basename(path), file=sys.stderr, leave=False)


def estimate_file(path: str, machine, policy: str | None, jerk: float | None, strict: bool,
                  quiet: bool = True) -> Estimate:
    from ..gcode import GcodeReader
    from ..planner import StreamPlanner

    policy = policy or machine.junction_policy
    reader = GcodeReader(path, machine, strict=strict)
    planner = StreamPlanner(machine, policy=policy, jerk=jerk)
    time = TimeSummary()
    bar = _progress(path, quiet)
    try:
        with located(path):
            for moves in reader.batches():
                for m, p in planner.feed(moves, reader.limits):
                    time.add(m, p)
                if bar is not None:
                    done = getattr(reader, "bytes_read", None)
                    if done is not None:
                        bar.update(done - bar.n)
            for m, p in planner.finish():
                time.add(m, p)
    finally:
        if bar is not None:
            bar.close()
    return Estimate(path, reader.summary, time, list(reader.layer_z), list(reader.features), policy,
                    machine.name)


def _machine(args):
    from ..config import machine_from_args

    return machine_from_args(args)


def _estimate_job(job):
    """Worker for --jobs: returns (path, json dict) or (path, error text)."""
    path, args = job
    try:
        est = estimate_file(path, _machine(args), args.policy, args.jerk, args.strict, quiet=True)
        return path, est.to_json(), None
    except GcodeplanError as err:
        return path, None, str(err)


def print_text(est: Estimate, out=None) -> None:
    t, s = est.time, est.parse
    w = (out or sys.stdout).write
    w(f"{est.path}\n")
    w(f"  machine {est.machine_name}, policy {est.policy}\n")
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
    layers = t.layers(est.layer_z)
    if layers:
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
    unknown = getattr(s, "unknown_commands", {}) or {}
    if unknown:
        items = ", ".join(f"{k}×{v}" for k, v in sorted(unknown.items(), key=lambda kv: -kv[1])[:12])
        w(f"  not modelled (counted): {items}\n")


def run(args) -> int:
    if args.jobs < 1:
        raise GcodeplanError("--jobs must be at least 1")
    if args.jerk is not None and not (args.jerk > 0):
        raise GcodeplanError("--jerk must be a positive number (mm/s³)")
    machine = _machine(args)  # fail early on a bad machine, before any worker starts
    if len(args.files) == 1:
        est = estimate_file(args.files[0], machine, args.policy, args.jerk, args.strict, quiet=args.quiet)
        if args.json:
            print(json.dumps(est.to_json(), indent=1))
        else:
            print_text(est)
        return 0
    jobs = [(f, args) for f in args.files]
    if args.jobs > 1:
        import multiprocessing as mp

        with mp.get_context("fork").Pool(min(args.jobs, len(jobs))) as pool:
            results = pool.map(_estimate_job, jobs, chunksize=1)
    else:
        results = [_estimate_job(j) for j in jobs]
    failed = 0
    if args.json:
        print(json.dumps([r if r is not None else {"file": p, "error": e} for p, r, e in results], indent=1))
    else:
        width = max(len(p) for p, _, _ in results)
        print(f"{'file':<{width}}  {'total':>10}  {'seconds':>12}  {'naive':>10}  {'moves':>9}  {'layers':>6}")
        for p, r, e in results:
            if r is None:
                print(f"{p:<{width}}  error: {e}")
                continue
            print(f"{p:<{width}}  {r['total_time_hms']:>10}  {r['total_time_s']:>12.3f}  "
                  f"{hms(r['naive_time_s']):>10}  {r['moves']:>9}  {r['layer_count']:>6}")
    for p, r, e in results:
        if r is None:
            failed += 1
            print(f"gcodeplan: {e}", file=sys.stderr)
    return 2 if failed else 0
