"""Benchmark: 1-D profiles solved per second
(``python tools/bench.py profiles [--n N] [--ruckig-n M] [--against OLD_SCURVE_PY]``).

Measures, in one run on this machine and one core:
  * ``profiles.scurve_durations`` on N random feasible S-curves (planner-like moves: 0.05-200 mm, end speeds
    anywhere the limits allow): the batch (argument checks fused into one njit pass, Newton cases iterated in
    lockstep), and a plain loop over the scalar ``scurve_duration_kernel`` (what compiled callers such as the
    planner get; bit-identical results);
  * with ``--against FILE``, the same two for another version of ``profiles/scurve.py`` (e.g. the last commit's:
    ``git show HEAD:src/gcodeplan/profiles/scurve.py > /tmp/old.py``), for a before/after under the same load,
    and the largest relative difference of the durations;
  * ``profiles.trapezoid_durations`` on the same moves;
  * ruckig's Python binding (1 DoF, ``Ruckig.calculate``) on the first M of them, and the agreement of the
    durations (max relative difference).
Prints a Markdown table for the README.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def make_cases(n: int, seed: int = 1) -> dict[str, np.ndarray]:
    from gcodeplan import profiles
    from gcodeplan.profiles.scurve import _scurve_max_end_loop

    rng = np.random.default_rng(seed)
    h = 10 ** rng.uniform(np.log10(0.05), np.log10(200.0), n)
    v_max = rng.uniform(50.0, 500.0, n)
    a_max = 10 ** rng.uniform(np.log10(500.0), np.log10(20000.0), n)
    j_max = 10 ** rng.uniform(4.0, 7.0, n)
    v_start = v_max * rng.uniform(0.0, 1.0, n) * (rng.uniform(size=n) < 0.7)
    # an end speed that can be reached: a fraction of the highest reachable one
    top = np.empty(n)
    _scurve_max_end_loop(h, v_max, a_max, j_max, v_start, top)
    v_end = top * rng.uniform(0.0, 1.0, n) * (rng.uniform(size=n) < 0.7)
    cases = {"distance": h, "v_max": v_max, "a_max": a_max, "j_max": j_max, "v_start": v_start, "v_end": v_end}
    ok = np.isfinite(profiles.scurve_durations(**cases))
    return {k: v[ok] for k, v in cases.items()}


def best_rate(fn, n: int, repeat: int = 5) -> float:
    fn()   # compile / warm up
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def ruckig_rate(c: dict[str, np.ndarray], m: int) -> tuple[float, float, int]:
    import ruckig

    otg = ruckig.Ruckig(1)
    inp = ruckig.InputParameter(1)
    traj = ruckig.Trajectory(1)
    durs = np.full(m, np.nan)
    t0 = time.perf_counter()
    for i in range(m):
        inp.current_position = [0.0]
        inp.current_velocity = [c["v_start"][i]]
        inp.current_acceleration = [0.0]
        inp.target_position = [c["distance"][i]]
        inp.target_velocity = [c["v_end"][i]]
        inp.target_acceleration = [0.0]
        inp.max_velocity = [c["v_max"][i]]
        inp.max_acceleration = [c["a_max"][i]]
        inp.max_jerk = [c["j_max"][i]]
        try:
            if otg.calculate(inp, traj) == ruckig.Result.Working:
                durs[i] = traj.duration
        except ruckig.RuckigError:
            pass
    rate = m / (time.perf_counter() - t0)
    return rate, durs


def load_against(path: str):
    """Another version of profiles/scurve.py as a sibling module of the current one, so that its relative
    imports (.core) resolve."""
    import importlib.util
    import shutil
    import tempfile
    from pathlib import Path

    # numba caches next to the source: give it a private copy
    tmp = Path(tempfile.mkdtemp(prefix="bench_scurve_")) / "scurve_against.py"
    shutil.copy(path, tmp)
    spec = importlib.util.spec_from_file_location("gcodeplan.profiles._scurve_against", tmp)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv: list[str]) -> int:
    from gcodeplan import profiles
    from gcodeplan.profiles.scurve import _scurve_durations_loop

    ap = argparse.ArgumentParser(prog="bench.py profiles")
    ap.add_argument("--n", type=int, default=2_000_000, help="S-curves per timed batch (default 2e6)")
    ap.add_argument("--ruckig-n", type=int, default=50_000, help="profiles given to ruckig (default 5e4)")
    ap.add_argument("--against", metavar="FILE", help="another scurve.py to time in the same run")
    args = ap.parse_args(argv)

    c = make_cases(args.n)
    n = c["distance"].shape[0]
    out = np.empty(n)
    cols = (c["distance"], c["v_max"], c["a_max"], c["j_max"], c["v_start"], c["v_end"])
    rows = []
    notes = []
    if args.against:
        old = load_against(args.against)
        old_api = best_rate(lambda: old.scurve_durations(**c), n)
        old_raw = best_rate(lambda: old._scurve_durations_loop(*cols, out), n)
        rows += [(f"before ({args.against}): `scurve_durations`", old_api),
                 (f"before ({args.against}): `scurve_duration_kernel` loop", old_raw)]
        new, was = profiles.scurve_durations(**c), old.scurve_durations(**c)
        rel = np.abs(new - was) / was
        notes.append(f"durations now vs before: max relative difference {np.nanmax(rel):.1e}, "
                     f"NaN in the same places: {bool((np.isnan(new) == np.isnan(was)).all())}")
    api = best_rate(lambda: profiles.scurve_durations(**c), n)
    raw = best_rate(lambda: _scurve_durations_loop(*cols, out), n)
    trap = best_rate(lambda: profiles.trapezoid_durations(c["distance"], c["v_max"], c["a_max"], c["v_start"],
                                                          c["v_end"]), n)
    rows += [("gcodeplan `scurve_durations` (fused checks, lockstep Newton)", api),
             ("gcodeplan `scurve_duration_kernel` loop (scalar kernel, no checks)", raw),
             ("gcodeplan `trapezoid_durations`", trap)]
    m = min(args.ruckig_n, n)
    try:
        rk_rate, rk = ruckig_rate(c, m)
        ours = profiles.scurve_durations(**{k: v[:m] for k, v in c.items()})
        ok = np.isfinite(rk)
        rel = np.abs(ours[ok] - rk[ok]) / rk[ok]
        notes.append(f"durations vs ruckig on {ok.sum()} of {m} profiles (ruckig failed on {m - ok.sum()}): "
                     f"median relative difference {np.median(rel):.1e}, "
                     f"{np.mean(rel <= 1e-9) * 100:.2f} % within 1e-9")
        rows.append(("ruckig Python binding, `Ruckig.calculate` (1 DoF)", rk_rate))
    except ImportError:
        notes.append("ruckig not installed: no comparison")
    print(f"{n} feasible random S-curves (0.05-200 mm, 50-500 mm/s, 500-20000 mm/s², 1e4-1e7 mm/s³), one core\n")
    print("| solver | profiles per second |")
    print("|---|---:|")
    for name, rate in rows:
        print(f"| {name} | {rate / 1e6:.2f} M/s |")
    print()
    for note in notes:
        print(note)
    return 0
