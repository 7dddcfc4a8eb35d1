"""gcodeplan/_jit.py: kernels interpreted for tiny inputs give exactly what numba's compiled kernels give.

The interpreted side always runs in a fresh process that has never imported numba (once numba is active in a
process every kernel is compiled), and asserts that numba stayed out of it; the compiled side runs here.
"""
from __future__ import annotations

import gzip
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan import _jit
from gcodeplan.pipeline import small_input

from conftest import shared_path

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "gcode_samples"

# the interpreted side: this module's _result() for every case, in a process that has never imported numba
_CHILD = r"""
import sys, json
sys.path.insert(0, sys.argv[2])
import test_jit
from gcodeplan import _jit
_jit.INTERPRET_BUDGET_S = 1e9                 # interpret everything, however long it takes
with _jit.interpreted():
    out = {json.dumps(case): test_jit._result(case) for case in json.loads(sys.argv[1])}
print(json.dumps({"results": out, "numba": "numba" in sys.modules, "fallbacks": _jit.fallbacks}))
"""


def _machine(spec):
    kind, _, where = spec.partition(":")
    if kind == "cfg":
        return gp.load_machine(klipper_config=where)
    if kind == "ini":
        return gp.load_machine(linuxcnc_ini=where)
    if kind == "generic":                        # a preset planned by its junction policy, not its firmware model
        return gp.load_machine(where, firmware="generic")
    return gp.load_machine(spec)


def _result(case):
    """[estimate JSON, sha256 of every field of every MOVE / PLAN / SEGMENT row] or ['error', message] for a case
    [path, machine spec, policy, jerk]; compiled or interpreted as the calling process runs its kernels."""
    import hashlib

    path, preset, policy, jerk = case
    m = _machine(preset)
    try:
        e = gp.estimate(path, m, policy=policy, jerk=jerk)
        p = gp.plan(path, m, policy=policy, jerk=jerk)
    except gp.GcodeplanError as err:
        return ["error", str(err)]
    h = hashlib.sha256()
    for arr in (p.moves, p.plan, p.segments):
        for name in arr.dtype.names:
            h.update(np.ascontiguousarray(arr[name]).tobytes())
    return [json.dumps(e.to_json(), sort_keys=True), h.hexdigest()]


def _compiled(case):
    _jit.activate()
    return _result(case)


def _interpreted(cases):
    r = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(cases), str(Path(__file__).parent)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def small_samples(tmp_path_factory):
    """The first ≤ 16 KB (whole lines) of every text sample: each a tiny program of its own kind."""
    d = tmp_path_factory.mktemp("small")
    out = []
    for p in sorted(SAMPLES.iterdir()):
        if p.suffix in (".gcode", ".ngc"):
            data = p.read_bytes()[:_jit.SMALL_INPUT_BYTES]
            data = data[:data.rfind(b"\n") + 1]
            q = d / p.name
            q.write_bytes(data)
            out.append(str(q))
    assert len(out) >= 8
    return out


def test_interpreted_kernels_plan_every_sample_bit_for_bit(small_samples):
    """Every sample × every junction policy, the marlin machine (generic planning) and S-curves: the estimate
    JSON and every field of every MOVE / PLAN / SEGMENT row are identical, with numba never imported and no
    kernel falling back."""
    _jit.activate()
    cases = []
    for path in small_samples:
        for policy in ("klipper", "junction-deviation", "classic-jerk", "blend", "exact-stop"):
            cases.append([path, "klipper", policy, None])
        cases.append([path, "generic:marlin", None, None])
        cases.append([path, "klipper", None, 20000.0])
    got = _interpreted(cases)
    assert got["numba"] is False
    assert got["fallbacks"] == []
    differ = [c for c in cases if got["results"][json.dumps(c)] != _compiled(c)]
    assert differ == []
    # and the cases are real plans, not a shared error (classic jerk needs per-axis jerks Klipper's preset lacks;
    # the LinuxCNC programs' arcs are out of the printer's range, and on a printer the plasma program's lines led
    # by an axis word are unknown commands, so its first arc ends off its circle in every case; Klipper refuses the
    # arc spiral's G20, an error in every Klipper case)
    errors = [(json.loads(c), v[1]) for c, v in got["results"].items() if v[0] == "error"
              and not json.loads(c)[0].endswith(("linuxcnc_plasmatest.ngc", "linuxcnc_arcspiral.ngc"))]
    assert len(errors) <= len(small_samples) + 1, errors


def test_interpreted_kernels_on_klipper_configs_and_linuxcnc(small_samples, tmp_path):
    """Klipper printer.cfg machines (cartesian, corexy, delta, input shaper, pressure advance: the vendored
    configs) and LinuxCNC's planner with its mill .ini: identical, numba-free."""
    _jit.activate()
    ref = REPO / "tests" / "data" / "reference" / "klipper"
    cfgs = [ref / "cartesian_corpus.cfg", ref / "corexy_corpus.cfg", ref / "extensions" / "delta.cfg",
            ref / "extensions" / "shaper_corexy.cfg", ref / "extensions" / "pa_cartesian.cfg"]
    printer = [p for p in small_samples if p.endswith(".gcode")]
    cases = [[p, f"cfg:{c}", None, None] for c in cfgs for p in printer[:3]]
    # LinuxCNC's mill (vendored in tests/data/reference too, so this never drops out silently); interpreting its
    # servo-cycle simulation is slow: the first 60 lines of each program
    ini = shared_path("reference", "linuxcnc", "config", "mill.ini")
    n_printer = len(cases)
    for p in small_samples:
        if p.endswith(".ngc"):
            short = tmp_path / Path(p).name
            short.write_text("".join(Path(p).read_text().splitlines(keepends=True)[:60]) + "M2\n")
            cases.append([str(short), f"ini:{ini}", "linuxcnc", None])
    assert len(cases) - n_printer >= 2          # the two LinuxCNC samples
    got = _interpreted(cases)
    # the only way out of Python allowed: LinuxCNC's servo-cycle simulation, whose arrays grow with the program's
    # duration, is compiled at once (MAX_INTERPRETED_ELEMENTS); everything before it was interpreted
    assert {tuple(f) for f in got["fallbacks"]} <= {("execute_kernel", "an array too long to interpret")}
    assert [c for c in cases if got["results"][json.dumps(c)] != _compiled(c)] == []
    assert sum(1 for v in got["results"].values() if v[0] != "error") >= len(cases) // 2


def test_differential_fuzz_round():
    """tools/fuzz.py --differential: mutated corpus programs planned interpreted (fresh worker without numba)
    and compiled give identical rows; the long round's figure is in the README."""
    sys.path.insert(0, str(REPO / "tools"))
    import fuzz

    st = fuzz.differential(5, 1000, None, log=lambda *a: None)
    assert st.cases == 1000
    assert st.failures == 0, st.signatures


def _child(code: str, *args, env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -c code args...`` in a fresh process (which has not imported numba), checked for success."""
    r = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                       env=None if env is None else {**os.environ, **env})
    assert r.returncode == 0, r.stderr
    return r


def _library_estimate_json(path) -> str:
    """gp.estimate(path).to_json() in this process with compiled kernels, as canonical JSON text."""
    _jit.activate()
    return json.dumps(json.loads(json.dumps(gp.estimate(str(path)).to_json())), sort_keys=True)


def test_tiny_estimate_never_imports_numba(tmp_path):
    """`gcodeplan estimate` and `parse` of a one-line file run without numba (the start-up target), and give
    what the compiled planner gives."""
    f = tmp_path / "one.gcode"
    f.write_text("G1 X10 F600\n")
    code = ("import sys, io, contextlib; from gcodeplan.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n    rc = main(['parse', sys.argv[1]])\n"
            "rc |= main(['estimate', '--json', sys.argv[1]])\n"
            "print('NUMBA', 'numba' in sys.modules, file=sys.stderr)\nsys.exit(rc)")
    r = _child(code, f)
    assert "NUMBA False" in r.stderr
    est = json.loads(r.stdout)
    _jit.activate()
    assert est["total_time_s"] == gp.estimate(str(f)).total_time_s
    # hand-worked: 10 mm at 10 mm/s with Klipper's preset (accel 3000): 1 s + the ramp's extra v/a = 1/300 s
    assert est["total_time_s"] == pytest.approx(1.0 + 10.0 / 3000.0, rel=1e-12)


def test_a_run_past_the_interpreting_budget_goes_compiled_with_the_same_result(tmp_path):
    """Past INTERPRET_BUDGET_S the outermost kernel call restores its arrays and numba takes over mid-run:
    the estimate is the compiled one, bit for bit."""
    f = tmp_path / "arcs.gcode"
    f.write_text("G21 G90\nG1 X10 Y0 F3000\n" + "G2 X10 Y0 I-10 J0\nG3 X10 Y0 I-10 J0\n" * 20 + "G1 X0 Y0\n")
    code = ("import sys, json; import gcodeplan as gp; from gcodeplan import _jit\n"
            "_jit.INTERPRET_BUDGET_S = 0.002\n"
            "e = gp.estimate(sys.argv[1])\n"
            "print(json.dumps({'est': e.to_json(), 'numba': 'numba' in sys.modules, 'fallbacks': _jit.fallbacks}))")
    got = json.loads(_child(code, f).stdout)
    assert got["numba"] is True
    assert any("too long" in why for _, why in got["fallbacks"])
    assert json.dumps(got["est"], sort_keys=True) == _library_estimate_json(f)


def test_what_counts_as_small(tmp_path):
    small = tmp_path / "s.gcode"
    small.write_text("G1 X1\n" * 100)
    big = tmp_path / "b.gcode"
    big.write_text("G1 X1\n" * (_jit.SMALL_INPUT_BYTES // 6 + 1))
    gz = tmp_path / "s.gcode.gz"
    gz.write_bytes(gzip.compress(b"G1 X1\n" * 100))
    assert small_input(str(small)) and small_input(small)
    assert not small_input(str(big))
    assert not small_input(str(gz))                    # compressed: its size says nothing
    assert not small_input("-") and not small_input(str(tmp_path / "missing.gcode"))
    assert small_input(["G1 X1\n"] * 10) and not small_input(["G1 X1\n"] * 10_000)
    assert not small_input(iter(["G1 X1\n"]))           # a stream: unknown size
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert not small_input(str(fifo))                  # a pipe: unknown size, and its first bytes are not ours


def test_step_runs_never_interpret():
    """A step sink does work per step: a run with one never interprets (a tiny file can ask for millions)."""
    from gcodeplan.pipeline import Run, run
    from gcodeplan.stepper.source import StepSink

    assert StepSink.interpretable is False
    seen = []

    class Spy(gp.pipeline.Sink):
        interpretable = False

        def add(self, piece):
            seen.append(_jit._interpret_depth)

    run(["G1 X10 F600\n"], gp.load_machine("klipper"), sinks=[Spy()])
    assert seen == [0]
    assert Run(["G1 X10 F600\n"], gp.load_machine("klipper")).small


# ------------------------------------------------------------------ the interpreter's rules, one by one
def _kernel(fn, **options):
    """A Kernel with its compiled dispatcher, in this process (numba active)."""
    numba = _jit.numba_module()
    k = _jit.Kernel(fn, options)
    k.dispatcher = numba.njit(**options)(fn)
    return k


def _digits(buf, out):
    # uint8 arithmetic: numba computes in int64 (c - 58 is negative), NumPy's uint8 scalars would wrap
    n = 0
    for i in range(buf.shape[0]):
        c = buf[i]
        if c - 58 < 0 and c - 48 >= 0:
            out[n] = c - 48
            n += 1
    return n


def _flags_field(rows):
    # a field named like an ndarray attribute: numba reads the field
    t = 0
    for i in range(rows.shape[0]):
        t += rows[i].flags * 2
        rows[i].flags = 1
    return t


def _divide(x, out):
    # Python raises on 1.0 / 0.0, numba (error_model numpy) gives inf: the call falls back, after restoring out
    out[0] = 99.0
    return 1.0 / x


def test_narrow_integers_are_widened_as_numba_does():
    k = _kernel(_digits)
    buf = np.frombuffer(b"G1 X12.5", dtype=np.uint8).copy()
    out_i, out_c = np.zeros(8, np.uint8), np.zeros(8, np.uint8)
    n_i = k._interpret((buf, out_i))
    n_c = k.dispatcher(buf, out_c)
    assert n_i == n_c == 4 and type(n_i) is int
    assert out_i.tolist() == out_c.tolist() == [1, 1, 2, 5, 0, 0, 0, 0]


def test_a_field_named_flags_reads_the_field():
    dt = np.dtype([("x", "f8"), ("flags", "u1")])
    a, b = np.zeros(3, dt), np.zeros(3, dt)
    a["flags"] = b["flags"] = [1, 2, 3]
    k = _kernel(_flags_field)
    assert k._interpret((a,)) == k.dispatcher(b) == 12
    assert a.tobytes() == b.tobytes()


def test_a_python_error_falls_back_to_the_compiled_kernel_on_restored_arrays():
    k = _kernel(_divide, error_model="numpy")
    out = np.zeros(1)
    before = len(_jit.fallbacks)
    assert k._interpret((0.0, out)) == math.inf          # numba's answer, not ZeroDivisionError
    assert out[0] == 99.0                                # written once, by the compiled run
    assert len(_jit.fallbacks) == before + 1 or len(_jit.fallbacks) == 100


def test_libm_functions_match_numba():
    """numba calls the C library's hypot and cbrt; CPython's math.hypot and NumPy's cbrt are other algorithms
    (they differ in the last bit): interpreted kernels see the C library's."""
    def maths(x, y):
        return math.hypot(x, y), np.cbrt(x * y)

    k = _kernel(maths)
    rng = np.random.default_rng(3)
    xs, ys = rng.random(3000) * 100.0, rng.random(3000) * 100.0
    same = sum(k._interpret((float(x), float(y))) == k.dispatcher(x, y) for x, y in zip(xs, ys))
    assert same == 3000
    # the test can fail: the plain Python versions do differ somewhere on these inputs
    assert any(math.hypot(x, y) != k.dispatcher(x, y)[0] or np.cbrt(x * y) != k.dispatcher(x, y)[1]
               for x, y in zip(xs, ys))


def test_kernels_pickle_by_name():
    """A kernel pickles as a function does (by module and name), before and after numba is active."""
    import pickle

    from gcodeplan.profiles import core

    k = _jit.Kernel(core.piece_position.py_func, {"cache": True})   # as the decorator makes it
    back = pickle.loads(pickle.dumps(k))
    assert back is core.piece_position                 # the module's own kernel (or dispatcher)
    assert back(0.0, 1.0, 2.0, 0.0, 3.0) == 12.0        # 0 + 1·3 + 2·9/2


def _total(a):
    t = 0.0
    for i in range(a.shape[0]):
        t += a[i]
    return t


def test_a_long_array_runs_compiled():
    """A kernel whose array is longer than MAX_INTERPRETED_ELEMENTS runs compiled at once: its loop is over that
    array (a tiny file's million-chord arc), and one interpreted call cannot stop at the budget."""
    k = _kernel(_total)
    a = np.full(_jit.MAX_INTERPRETED_ELEMENTS + 1, 0.5)
    before = len(_jit.fallbacks)
    assert k._interpret((a,)) == 0.5 * a.size
    assert len(_jit.fallbacks) == 100 or _jit.fallbacks[before:] == [("_total", "an array too long to interpret")]


_COMMAND = """import sys, io, contextlib, gc
sys.argv[0] = "gcodeplan"                    # this process is the command (cli._is_console_script)
from gcodeplan.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    rc = main(["estimate", "--json", sys.argv[1]])
print(out.getvalue(), end="")
print("STATE", "numba.np.arraymath" in sys.modules, "yaml" in sys.modules, gc.isenabled(), file=sys.stderr)
sys.exit(rc)
"""


def _command(path, env=None) -> tuple[dict, list[str]]:
    r = _child(_COMMAND, path, env=env)
    state = [ln for ln in r.stderr.splitlines() if ln.startswith("STATE")][-1].split()[1:]
    return json.loads(r.stdout), state


def test_the_command_loads_cached_kernels_without_numbas_registries():
    """A compiled run in the command's process: once the kernels are cached, numba's typing and lowering
    registries (numba.np.arraymath among them) are never imported, nor PyYAML, and the collector is back on;
    the estimate is the library's, bit for bit."""
    cube = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"         # 174 kB: compiled kernels
    _command(cube)                                                # makes sure every kernel is cached
    est, (arraymath, yaml, gc_on) = _command(cube)
    assert arraymath == "False" and gc_on == "True"
    assert yaml == "False"            # numba imports PyYAML only to read a .numba_config.yaml; there is none
    assert json.dumps(est, sort_keys=True) == _library_estimate_json(cube)


@pytest.mark.slow
def test_the_command_compiles_kernels_missing_from_the_cache(tmp_path):
    """With an empty numba cache the command compiles its kernels (numba refreshes its registries for that
    itself) and gives the library's estimate; a second run loads them from that cache, same bytes."""
    cube = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    cold, (arraymath, _, _) = _command(cube, env)
    assert arraymath == "True"                                    # compiling needed the registries
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))
    warm, (arraymath, _, _) = _command(cube, env)
    assert arraymath == "False"
    assert cold == warm
    assert json.dumps(cold, sort_keys=True) == _library_estimate_json(cube)
