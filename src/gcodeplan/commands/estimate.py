"""``gcodeplan estimate``: parse, plan, and account for the time of one or many files."""
from __future__ import annotations

import argparse
import json
import sys

from ..errors import GcodeplanError
from ..report.estimate import Estimate, print_text
from ..report.summary import hms
from .common import (add_machine_arguments, add_plan_arguments, check_plan_arguments, machine_from_args,
                     progress_bar)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help="G-code file(s)")
    add_machine_arguments(p)
    add_plan_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object (a list of them for many files)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="estimate many files in N parallel processes (default 1)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.add_argument("--per-line", metavar="OUT.csv",
                   help="also write the end time of every line that moves (line,end_time_s: Klipper's per-line CSV)")
    p.add_argument("--exclude-object", action="append", default=[], metavar="NAME",
                   help="estimate the print with this object cancelled, as Klipper's exclude_object runs it "
                        "(repeatable; names as the file labels them, case-insensitive)")


def estimate_source(source, machine, policy: str | None, jerk: float | None, strict: bool,
                    quiet: bool = True, exclude_objects=(), line_times: bool = False) -> Estimate:
    """gp.estimate with a progress bar on a terminal (per-line times only when asked: --per-line)."""
    from ..api import estimate

    bar, progress = progress_bar(source, quiet)
    try:
        return estimate(source, machine, policy, jerk, strict=strict, progress=progress,
                        exclude_objects=exclude_objects, line_times=line_times)
    finally:
        if bar is not None:
            bar.close()


def _estimate_job(job):
    """Worker for --jobs: returns (path, json dict) or (path, error text)."""
    path, args = job
    try:
        est = estimate_source(path, machine_from_args(args), args.policy, args.jerk, args.strict, quiet=True,
                              exclude_objects=args.exclude_object)
        return path, est.to_json(), None
    except GcodeplanError as err:
        return path, None, str(err)


def _worker_signals() -> None:
    """A --jobs worker dies of SIGINT / SIGTERM / SIGHUP as an ordinary process: its parent reports and cleans up."""
    import signal

    from ..signals import HANDLED

    for sig in HANDLED:
        signal.signal(sig, signal.SIG_DFL)


def _write_per_line(path: str, est: Estimate) -> None:
    """line,end_time_s rows (Klipper's per-line CSV format), written atomically."""
    from ..report.output import atomic_write_text

    line, end = est.line_times()
    rows = "".join(f"{int(n)},{t:.6f}\n" for n, t in zip(line.tolist(), end.tolist()))
    atomic_write_text(path, "source_line,end_time_s\n" + rows)


def run(args) -> int:
    if args.jobs < 1:
        raise GcodeplanError("--jobs must be at least 1")
    check_plan_arguments(args)
    machine = machine_from_args(args)  # fail early on a bad machine, before any worker starts
    if args.files.count("-") > 1:
        raise GcodeplanError("standard input (-) can be read once: give - at most once")
    if args.per_line and len(args.files) != 1:
        raise GcodeplanError("--per-line takes one FILE")
    if len(args.files) == 1:
        est = estimate_source(args.files[0], machine, args.policy, args.jerk, args.strict, quiet=args.quiet,
                              exclude_objects=args.exclude_object, line_times=bool(args.per_line))
        if args.per_line:
            _write_per_line(args.per_line, est)
        if args.json:
            print(json.dumps(est.to_json(), indent=1))
        else:
            print_text(est)
        return 0
    jobs = [(f, args) for f in args.files]
    results = None
    if args.jobs > 1:
        import multiprocessing as mp

        pool = mp.get_context("fork").Pool(min(args.jobs, len(jobs)), initializer=_worker_signals)
        try:
            results = pool.map(_estimate_job, jobs, chunksize=1)
            pool.close()         # workers leave on their own: no SIGTERM (Pool.terminate) into a worker
        finally:                 # that may hold the task queue's lock
            if results is None:  # interrupted or failed: stop the workers now
                pool.terminate()
            pool.join()
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
