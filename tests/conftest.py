"""Shared test fixtures: where the corpus and the peer reference figures live."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "gcode_samples"
# CI clones the repo with shared/ beside it; a developer checkout has it at ../shared too.
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
# GCODEPLAN_NO_SHARED=1: behave as a fresh clone does (no ../shared beside it), whatever is on disk, so that CI
# checks the README's promise that a bare clone still compares every stage with the firmware (.ci/run)
NO_SHARED = os.environ.get("GCODEPLAN_NO_SHARED", "") not in ("", "0")
SHARED_AVAILABLE = not NO_SHARED and SHARED.is_dir()
CORPUS = SHARED / "gcode"
REFERENCE = SHARED / "reference"
# The printer files of ../shared/gcode that Klipper ran (each has a per-line CSV in reference/klipper/per_line):
# tests are parametrized by this list, not by a listing of ../shared, so a bare clone collects the same tests
KLIPPER_CORPUS = ["cncjs_jscut_tball_pocket_laser.gcode", "cura413_ender3_cylinder30.gcode",
                  "prusaslicer25_cube20_marlin2.gcode", "prusaslicer25_multi_object_plate_relE.gcode",
                  "prusaslicer25_plate150_gyroid_big.gcode", "prusaslicer25_twisted_vase_spiral.gcode"]


# A compact copy of the peer references lives in the repository (tests/data/reference/README.md), so
# that a bare clone still checks agreement with Klipper; the full set stays in ../shared.
VENDORED = REPO / "tests" / "data" / "reference"


def vendored_path(*parts: str) -> Path | None:
    """Where a file of ../shared/<parts> is in the repository, or None: references under
    tests/data/reference/, G-code (``gcode/<name>`` and the reference's ``synthetic/<name>.gcode``,
    byte-identical copies) under gcode_samples/."""
    if not parts:
        return None
    if parts[0] == "reference":
        p = VENDORED.joinpath(*parts[1:])
        if p.is_file():
            return p
    if str(parts[-1]).endswith((".gcode", ".ngc")) and (parts[0] == "gcode" or parts[:3] == (
            "reference", "klipper", "synthetic")):
        p = SAMPLES / parts[-1]
        if p.is_file():
            return p
    return None


def shared_path(*parts: str) -> Path:
    """A path under ../shared; when ../shared is absent, the repository's copy of it
    (:func:`vendored_path`); skips the test when neither has it."""
    p = SHARED.joinpath(*parts)
    if SHARED_AVAILABLE:
        if p.exists():
            return p
    else:
        v = vendored_path(*parts)
        if v is not None:
            return v
    pytest.skip(f"{p} not available" + (" (GCODEPLAN_NO_SHARED is set)" if NO_SHARED else ""))


@pytest.fixture
def reference():
    """``reference(*parts)``: a file of ../shared/reference/<parts> (e.g. ``"klipper", "times.json"``),
    from ../shared when it is there, else from the vendored subset in tests/data/reference; skips when
    neither has it."""
    return lambda *parts: shared_path("reference", *parts)


@pytest.fixture
def samples() -> Path:
    return SAMPLES


# ----------------------------------------------------------------------------- MOVE rows for planner tests
import math
import numpy as np
from gcodeplan.machine import Axis, Machine
from gcodeplan.schema import (KIND_DWELL, KIND_EXTRUDE_ONLY, KIND_PRINT, KIND_TRAVEL, MOVE_DTYPE)


def same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape:
        return False
    for f in MOVE_DTYPE.names:
        x, y = a[f], b[f]
        if x.dtype.kind == "f":
            if not np.array_equal(x, y, equal_nan=True):
                return False
        elif not np.array_equal(x, y):
            return False
    return True


def klipper_machine(policy: str = "klipper", **kw) -> Machine:
    """The machine of the Klipper reference config (cartesian_corpus.cfg), stated by hand
    (Klipper's extruder defaults: ratio0 = 4·nozzle²/(π·(filament/2)²))."""
    ratio0 = 4.0 * 0.4 ** 2 / (math.pi * (1.75 * 0.5) ** 2)
    m = Machine(name="klipper-ref", flavor="klipper", max_velocity=300.0, max_accel=3000.0,
                square_corner_velocity=5.0, minimum_cruise_ratio=0.5, junction_policy=policy,
                max_extrude_only_velocity=300.0 * ratio0, max_extrude_only_accel=3000.0 * ratio0,
                instantaneous_corner_velocity=1.0)
    m.axes = {"x": Axis(), "y": Axis(), "z": Axis(max_velocity=15.0, max_accel=100.0), "e": Axis()}
    for k, v in kw.items():
        setattr(m, k, v)
    return m


def moves_from_points(points, feed_v=100.0, accel=3000.0, limits=0, exact_stop=0, first_line=1) -> np.ndarray:
    """One MOVE row per consecutive pair of points (x, y, z, e); kind from the geometry."""
    pts = np.asarray(points, dtype=float)
    if pts.shape[1] == 3:
        pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    n = len(pts) - 1
    mv = np.zeros(n, dtype=MOVE_DTYPE)
    for k, ax in enumerate("xyze"):
        mv[ax + "0"] = pts[:-1, k]
        mv[ax + "1"] = pts[1:, k]
    dxyz = pts[1:, :3] - pts[:-1, :3]
    de = pts[1:, 3] - pts[:-1, 3]
    d = np.sqrt((dxyz ** 2).sum(axis=1))
    kinematic = d >= 1e-9
    mv["kind"] = np.where(~kinematic, KIND_EXTRUDE_ONLY, np.where(de > 0, KIND_PRINT, KIND_TRAVEL))
    mv["move_d"] = np.where(kinematic, d, np.abs(de))
    mv["feed_v"] = feed_v
    mv["accel"] = accel
    mv["limits"] = limits
    mv["exact_stop"] = exact_stop
    mv["line"] = np.arange(first_line, first_line + n)
    mv["layer"] = -1
    mv["feature"] = -1
    return mv


def dwell_row(pos, dwell_t: float, line: int = 0, kind: int = KIND_DWELL) -> np.ndarray:
    r = np.zeros(1, dtype=MOVE_DTYPE)
    for k, ax in enumerate("xyze"):
        r[ax + "0"] = r[ax + "1"] = (list(pos) + [0.0] * 4)[k]
    r["kind"], r["dwell_t"], r["line"], r["feed_v"], r["accel"] = kind, dwell_t, line, 1.0, 1.0
    return r


def read_simple_gcode(path, accel=3000.0) -> np.ndarray:
    """Absolute-mode G0/G1 with X Y Z E F and SET_KINEMATIC_POSITION only (the synthetic files);
    positions are float(text) as Klipper's gcode_move makes them. F is modal, initial 25 mm/s."""
    pos = [0.0, 0.0, 0.0, 0.0]
    feed = 25.0
    rel_e = False
    rows = []
    for lineno, raw in enumerate(open(path), 1):
        line = raw.split(";")[0].strip()
        if not line:
            continue
        words = line.split()
        cmd = words[0].upper()
        if cmd == "SET_KINEMATIC_POSITION":
            for w in words[1:]:
                k, v = w.split("=")
                pos["XYZ".index(k.upper())] = float(v)
            continue
        if cmd in ("M82", "M83"):
            rel_e = cmd == "M83"
            continue
        if cmd not in ("G0", "G1"):
            assert cmd in ("G90", "G21"), f"{path}:{lineno}: unsupported {cmd}"
            continue
        new = list(pos)
        for w in words[1:]:
            letter, val = w[0].upper(), float(w[1:])
            if letter == "F":
                feed = val / 60.0
            elif letter == "E" and rel_e:
                new[3] = pos[3] + val
            else:
                new["XYZE".index(letter)] = val
        if new != pos:
            mv = moves_from_points([pos, new], feed_v=feed, accel=accel, first_line=lineno)
            rows.append(mv)
        pos = new
    return np.concatenate(rows)


def random_program(rng: np.random.Generator, n: int, n_limits: int = 1, dwell_p: float = 0.01,
                   exact_p: float = 0.0) -> np.ndarray:
    """A random but realistic mix: printing polylines (short zig-zags, arcs of chords, long
    lines, collinear runs), travels, retract / unretract (extrude-only), Z hops, dwells,
    zero-length moves, feed changes, occasional exact-stop moves and limits-row switches."""
    pts = [np.array([100.0, 100.0, 0.2, 0.0])]
    cur_feed = 50.0
    lim = 0
    out = []
    while sum(len(o) for o in out) < n:
        r = rng.random()
        p = pts[-1].copy()
        if r < 0.02 and n_limits > 1:
            lim = int(rng.integers(0, n_limits))
            continue
        if r < 0.1:
            cur_feed = float(rng.choice([5.0, 20.0, 40.0, 80.0, 150.0, 250.0, 400.0]))
        if r < 0.1 + dwell_p:
            out.append(dwell_row(p, float(rng.choice([0.0, 0.0005, 0.25])), line=0))
            continue
        kind = rng.random()
        seq = []
        if kind < 0.35:      # zig-zag of short segments
            step = rng.uniform(0.05, 2.0)
            ang = rng.uniform(0, 2 * np.pi)
            for k in range(int(rng.integers(2, 30))):
                a = ang + (np.pi / 2 if k % 2 else -np.pi / 2) * rng.uniform(0.2, 1.0)
                q = seq[-1].copy() if seq else p.copy()
                q[:2] += step * np.array([np.cos(a), np.sin(a)])
                q[3] += 0.03 * step
                seq.append(q)
        elif kind < 0.6:     # arc of chords / collinear run
            rad = rng.uniform(1, 50)
            turn = rng.choice([0.0, rng.uniform(0.01, 0.3)])
            ang = rng.uniform(0, 2 * np.pi)
            for k in range(int(rng.integers(2, 40))):
                ang += turn
                q = seq[-1].copy() if seq else p.copy()
                q[:2] += rad * 0.1 * np.array([np.cos(ang), np.sin(ang)])
                q[3] += 0.02 * rad * 0.1
                seq.append(q)
        elif kind < 0.75:    # long line / travel
            q = p.copy()
            q[:2] += rng.uniform(-80, 80, 2)
            if rng.random() < 0.5:
                q[3] += 0.03 * np.hypot(*(q[:2] - p[:2]))
            seq.append(q)
        elif kind < 0.85:    # retract, travel (maybe with z hop), unretract
            q = p.copy(); q[3] -= 0.8; seq.append(q)
            q = q.copy(); q[2] += rng.choice([0.0, 0.4]); q[:2] += rng.uniform(-20, 20, 2); seq.append(q)
            if q[2] != p[2]:
                q = q.copy(); q[2] = p[2]; seq.append(q)
            q = q.copy(); q[3] += 0.8; seq.append(q)
        elif kind < 0.9:     # retraction combined with XY (wipe)
            q = p.copy(); q[:2] += rng.uniform(-3, 3, 2); q[3] -= 0.5; seq.append(q)
        elif kind < 0.95:    # Z move (layer change), sometimes with E
            q = p.copy(); q[2] += rng.choice([0.2, 0.3, 2.0]); q[3] += rng.choice([0.0, 0.1]); seq.append(q)
        else:                # zero-length move and exact reversal
            seq.append(p.copy())
            q = p.copy(); q[0] += 5; seq.append(q)
            seq.append(p.copy())
        chain = [p] + seq
        mv = moves_from_points(chain, feed_v=cur_feed, accel=float(rng.choice([3000.0, 1250.0, 500.0])),
                               limits=lim)
        if exact_p and rng.random() < exact_p:
            mv["exact_stop"] = 1
        out.append(mv)
        pts.append(chain[-1])
    mv = np.concatenate(out)[:n]
    mv["line"] = np.arange(1, len(mv) + 1)
    return mv


def limits_variants(machine, n: int, rng: np.random.Generator) -> np.ndarray:
    """n LIMITS rows: the machine's, then variations (max_v, scv, mcr, accel caps, jerks)."""
    rows = np.repeat(machine.limits_row(), n)
    for k in range(1, n):
        rows[k]["max_v"] = rng.choice([100.0, 200.0, 300.0])
        rows[k]["scv"] = rng.choice([1.0, 5.0, 10.0])
        rows[k]["mcr"] = rng.choice([0.0, 0.25, 0.5, 0.9])
        rows[k]["junction_dev"] = rng.choice([0.005, 0.013, 0.05])
        rows[k]["icv"] = rng.choice([0.5, 1.0, 3.0])
    return rows


# ----------------------------------------------------------------------------- steps against Klipper's
def steps_window(ref, truncated_at=None) -> float | None:
    """Up to which time (s) the step file ``ref`` (an opened npz) holds every step: ``truncated_at`` (a file
    cut by the reference run itself, times.json's ``truncated_at_s``), the ``truncated_at_s`` key of a
    vendored prefix (tests/data/reference/vendor.py), whichever is earlier; None for a whole run."""
    if "truncated_at_s" in ref.files:
        cut = float(ref["truncated_at_s"])
        truncated_at = cut if truncated_at is None else min(truncated_at, cut)
    return truncated_at


def compare_with_klipper_steps(ours, ref, figures, tol_s, truncated_at=None) -> float:
    """Counts and net steps of the full run (Klipper's times.json ``figures``), then step for step against the
    reference npz ``ref`` (only steps before ``truncated_at`` s when the file is truncated, or is a vendored
    prefix: :func:`steps_window`). Returns the worst time difference (s); every step must be within ``tol_s``."""
    truncated_at = steps_window(ref, truncated_at)
    worst = 0.0
    for name, (t, d) in ours.items():
        full = figures[name]
        assert len(t) == full["n_steps"], f"{name}: {len(t)} steps, Klipper {full['n_steps']}"
        assert int(d.sum(dtype=np.int64)) == full["net_steps"], name
        if truncated_at is not None:
            keep = t < truncated_at
            t, d = t[keep], d[keep]
        rt, rd = ref[name], ref[name + "_dir"]
        assert len(t) == len(rt), f"{name}: {len(t)} steps in the window, Klipper {len(rt)}"
        assert np.array_equal(d, rd), f"{name}: directions differ"
        if len(t):
            err = float(np.max(np.abs(t - rt)))
            assert err < tol_s, f"{name}: worst step {err * 1e9:.1f} ns off"
            worst = max(worst, err)
    return worst


@pytest.fixture(autouse=True)
def _user_kinematics_unregistered():
    """A test that registers a kinematics of its own (docs/api.md's SCARA arm, a user plug-in) leaves the registry
    as it found it: the next test's "unknown kinematics" errors must not depend on the order tests ran in. The
    built-ins stay (they register once, on their module's import)."""
    from gcodeplan.kinematics import plugin

    before = set(plugin._REGISTRY)
    yield
    for name in set(plugin._REGISTRY) - before:
        if name not in plugin.KINEMATICS_MODULES:
            del plugin._REGISTRY[name]


# ----------------------------------------------------------------------------- numba's kernels, once
#: what the warm-up runs, two groups in two processes at once: the estimate and step paths every stage's tests use
_WARM_UP = (
    [["estimate", "-q", "--json", "{cube}"], ["estimate", "-q", "--json", "--policy", "blend", "{cube}"],
     ["estimate", "-q", "--json", "--jerk", "20000", "{cube}"], ["steps", "-q", "-o", "{tmp}/a.npz", "{cube}"],
     ["steps", "-q", "--compress", "-o", "{tmp}/b.npz", "--klipper-config", "{corexy}", "{square}"]],
    [["estimate", "-q", "--json", "--machine", "marlin", "{cube}"],
     ["steps", "-q", "-o", "{tmp}/c.npz", "--machine", "marlin", "{square}"],
     ["estimate", "-q", "--json", "--no-bounds", "--machine", "grbl", "{plasma}"],
     ["steps", "-q", "-o", "{tmp}/d.npz", "--no-bounds", "--machine", "grbl", "{plasma}"],
     ["estimate", "-q", "--json", "--linuxcnc-ini", "{mill}", "{plasma}"]],
)


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """With pytest-xdist's workers (``pytest -n auto``), compile the kernels most tests use once, before the
    workers start: numba's cache is shared, its compiling is not, so on a fresh clone every worker would compile
    the same kernels itself (about 4 of a fresh run's 12 minutes here). Two processes, one group each; a warm
    cache makes this a few seconds. Nothing here can fail the session: a test that needs a kernel compiles it."""
    import subprocess
    import sys
    import tempfile

    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None) \
            or config.getoption("collectonly"):
        return
    ref = REPO / "tests" / "data" / "reference"
    names = {"cube": SAMPLES / "prusaslicer25_cube20_marlin2.gcode", "square": SAMPLES / "b_square.gcode",
             "plasma": SAMPLES / "linuxcnc_plasmatest.ngc", "mill": ref / "linuxcnc" / "config" / "mill.ini",
             "corexy": ref / "klipper" / "corexy_corpus.cfg"}
    with tempfile.TemporaryDirectory() as tmp:
        procs = []
        for group in _WARM_UP:
            argvs = [[a.format(tmp=tmp, **{k: str(v) for k, v in names.items()}) for a in argv] for argv in group]
            code = ("import sys\nfrom gcodeplan.cli import main\n"
                    f"for argv in {argvs!r}:\n    main(argv)\n")
            procs.append(subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, cwd=str(REPO)))
        for p in procs:
            try:
                p.wait(timeout=900)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def toolhead_steps_line_by_line(machine, text: str) -> dict:
    """{stepper: (times, dirs)} a ``Toolhead(machine, steps=True, block_lines=1)`` hands out when fed ``text``
    one line at a time and then closed: every ``th.steps()`` concatenated, as a firmware loop would collect them."""
    import gcodeplan as gp

    th = gp.Toolhead(machine, steps=True, block_lines=1)
    parts: dict = {}
    for line in text.splitlines(keepends=True):
        th.gcode(line)
        for k, (t, d) in th.steps().items():
            parts.setdefault(k, []).append((t, d))
    th.close()
    for k, (t, d) in th.steps().items():
        parts.setdefault(k, []).append((t, d))
    return {k: (np.concatenate([p[0] for p in v]), np.concatenate([p[1] for p in v])) for k, v in parts.items()}
