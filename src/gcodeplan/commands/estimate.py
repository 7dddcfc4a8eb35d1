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
                   help="also write the end time of every line that moves (line,end_time_s: Klipper's per-line "
                        "CSV); '-': to standard output, the summary then going to standard error")
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


class WorkerDied(Exception):
    """A --jobs worker ended without an answer (killed: the out-of-memory killer, ``kill``)."""


def _worker_loop(conn) -> None:
    """A --jobs worker: estimate each job the parent sends, answer, until told to stop (None)."""
    from ..signals import child_defaults

    child_defaults()     # dies of SIGINT / SIGTERM / SIGHUP as an ordinary process (nohup: stays ignored)
    while True:
        try:
            job = conn.recv()
        except EOFError:                 # the parent is gone
            return
        if job is None:
            return
        try:
            answer = ("done",) + _estimate_job(job)
        except Exception as err:  # an internal error: the parent reports it as one
            import traceback

            traceback.print_exc()
            answer = ("internal", job[0], repr(err), None)
        conn.send(answer)


def _how_it_ended(exitcode: int | None) -> str:
    import signal

    if exitcode is None:
        return "it stopped answering"
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return f"killed by {name}" + (": the out-of-memory killer, or kill -9" if name == "SIGKILL" else "")
    return f"it exited with status {exitcode}"


def run_jobs(jobs: list, n: int) -> list:
    """Estimate ``jobs`` ((path, args) pairs) in ``n`` forked workers, in order of the jobs; each worker takes
    the next file when it answers. A worker that dies (killed, out of memory) raises :class:`WorkerDied`
    naming its file; the others are stopped at once, as on an interruption."""
    import multiprocessing as mp
    from multiprocessing.connection import wait

    ctx = mp.get_context("fork")
    results: list = [None] * len(jobs)
    order = iter(range(len(jobs)))
    workers = []          # [process, connection, index of the job it runs or None]
    try:
        for _ in range(min(n, len(jobs))):
            here, there = ctx.Pipe()
            proc = ctx.Process(target=_worker_loop, args=(there,), daemon=True, name="gcodeplan-estimate")
            proc.start()
            there.close()
            workers.append([proc, here, None])

        def give(w) -> None:
            w[2] = next(order, None)
            try:
                w[1].send(None if w[2] is None else jobs[w[2]])
            except OSError:          # it died between two files (a closed pipe): not standard output's fault
                if w[2] is None:
                    return
                w[0].join(1.0)
                raise WorkerDied(f"{jobs[w[2]][0]}: the worker given it had died, "
                                 f"{_how_it_ended(w[0].exitcode)}; the other workers were stopped") from None

        for w in workers:
            give(w)
        while True:
            busy = {}
            for w in workers:
                if w[2] is not None:
                    busy[w[1]] = w
                    busy[w[0].sentinel] = w
            if not busy:
                break
            for ready in wait(list(busy)):
                w = busy[ready]
                if w[2] is None:
                    continue          # its answer and its end in the same round
                try:
                    answer = w[1].recv() if w[1].poll() else None
                except (EOFError, OSError):
                    answer = None
                if answer is None:
                    if ready is w[1] or w[0].is_alive():
                        w[0].join(0.5)
                    if w[0].is_alive() and ready is not w[0].sentinel:
                        continue
                    w[0].join()
                    raise WorkerDied(f"{jobs[w[2]][0]}: the worker estimating it died, "
                                     f"{_how_it_ended(w[0].exitcode)}; the other workers were stopped")
                if answer[0] == "internal":
                    raise RuntimeError(f"{answer[1]}: {answer[2]} (in a --jobs worker)")
                results[w[2]] = answer[1:]
                give(w)
    finally:
        for proc, conn, job in workers:
            if job is not None and proc.is_alive():   # interrupted or failed: stop the workers now
                proc.kill()
        for proc, conn, _ in workers:
            proc.join()
            conn.close()
    return results


def _note_nothing_moved(path: str, d: dict) -> None:
    """A one-line note on stderr when a file moves nothing: 0 s is then no estimate of anything (an empty
    file, a wrong file, a program of comments). The printed summary and the --json keys stay as they are."""
    if d.get("total_time_s", 0.0) != 0.0 or d.get("moves", 0):
        return
    lines = d.get("lines", 0)
    what = "is empty" if not lines else f"has no motion ({lines} line{'s' if lines != 1 else ''}, no move, dwell or wait)"
    print(f"gcodeplan: note: {path} {what}: its time is 0 s", file=sys.stderr)


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
    if args.per_line:
        from ..report.output import resolve_output

        if resolve_output(args.per_line).kind == "stdout" and args.json:   # checked before any planning
            raise GcodeplanError("--per-line - and --json both want standard output: name a file for one")
    if len(args.files) == 1:
        est = estimate_source(args.files[0], machine, args.policy, args.jerk, args.strict, quiet=args.quiet,
                              exclude_objects=args.exclude_object, line_times=bool(args.per_line))
        summary = sys.stdout
        if args.per_line:
            _write_per_line(args.per_line, est)
            if resolve_output(args.per_line).kind == "stdout":
                summary = sys.stderr      # the CSV went to standard output: the summary goes beside it
        d = est.to_json()
        _note_nothing_moved(est.path, d)
        if args.json:
            print(json.dumps(d, indent=1))
        else:
            print_text(est, summary)
        return 0
    jobs = [(f, args) for f in args.files]
    if args.jobs > 1:
        try:
            results = run_jobs(jobs, args.jobs)
        except WorkerDied as err:
            print(f"gcodeplan: {err}", file=sys.stderr)
            return 1
    else:
        results = [_estimate_job(j) for j in jobs]
    for p, r, _ in results:
        if r is not None:
            _note_nothing_moved(p, r)
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
