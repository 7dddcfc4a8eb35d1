"""SIGTERM, SIGHUP and SIGINT end gcodeplan cleanly: exit status 128 + signal, no temporary file left,
the previous output untouched; stale temporary files of a kill -9 are never output and are swept.

The real CLI runs in a subprocess on a generated big file (and on the 50 MB corpus file, slow); the
signal is sent once the command has made its temporary spool, i.e. mid-run.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import shared_path
from gcodeplan import cli, signals
from gcodeplan.report import output

SIGNALS = [signal.SIGTERM, signal.SIGHUP, signal.SIGINT]


@pytest.fixture(scope="module")
def big_file(tmp_path_factory):
    """~300 000 long zig-zag moves: planning and stepping take seconds, enough to be interrupted."""
    p = tmp_path_factory.mktemp("big") / "big.gcode"
    with open(p, "w") as fh:
        fh.write("G90\nM83\nG1 Z0.2 F600\n")
        for i in range(300_000):
            fh.write(f"G1 X{(i % 2) * 180 + 10:.0f} Y{10 + (i % 1800) * 0.1:.1f} E0.5 F12000\n")
    return str(p)


@pytest.fixture(scope="module")
def long_file(tmp_path_factory):
    """The same zig-zag, 1.44 M moves (37 MB): an estimate takes well over a second. (It took 0.7 s on big_file
    once planning overlapped parsing, and once finished before the signal came.)"""
    p = tmp_path_factory.mktemp("long") / "long.gcode"
    block = "".join(f"G1 X{(i % 2) * 180 + 10:.0f} Y{10 + (i % 1800) * 0.1:.1f} E0.5 F12000\n" for i in range(3600))
    with open(p, "w") as fh:
        fh.write("G90\nM83\nG1 Z0.2 F600\n")
        fh.write(block * 400)
    return str(p)


def _leftovers(directory):
    return sorted(n for n in os.listdir(directory) if n.startswith("."))


def _handles_sigterm(pid: int) -> bool:
    """True once the process catches SIGTERM (Linux /proc: gcodeplan's handlers are installed)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught >> (signal.SIGTERM - 1) & 1)


def _run_and_signal(argv, directory, sig, wait_for_temp=True, timeout=120.0):
    """Start the CLI, wait until it has a temporary file or spool in ``directory`` (or, without one, its
    handlers are in place), send ``sig``."""
    proc = subprocess.Popen([sys.executable, "-m", "gcodeplan.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    try:
        while not (_leftovers(directory) if wait_for_temp else _handles_sigterm(proc.pid)):
            if proc.poll() is not None:
                pytest.fail(f"finished before it could be interrupted: {proc.returncode} {proc.stderr.read()}")
            if time.monotonic() - t0 > timeout:
                pytest.fail("no temporary file appeared")
            time.sleep(0.02)
        time.sleep(0.3)
        assert proc.poll() is None, "finished before the signal"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_steps_interrupted_leaves_nothing_and_keeps_the_old_output(tmp_path, big_file, sig):
    out = tmp_path / "s.npz"
    out.write_bytes(b"previous run")
    rc, err = _run_and_signal(["steps", big_file, "-o", str(out), "-q"], tmp_path, sig)
    assert rc == 128 + sig, err
    name = signal.Signals(sig).name
    # (a signal during numba's first compilation may add llvmlite's "Exception ignored" note before it)
    assert err.splitlines()[-1] == ("gcodeplan: interrupted" if sig == signal.SIGINT
                                    else f"gcodeplan: terminated by {name}"), err
    assert _leftovers(tmp_path) == [] and out.read_bytes() == b"previous run"


def test_steps_compact_and_csv_interrupted_leave_nothing(tmp_path, big_file):
    rc, err = _run_and_signal(["steps", big_file, "-o", str(tmp_path / "s.npz"), "--format", "compact",
                               "--csv", str(tmp_path / "csv"), "-q"], tmp_path, signal.SIGTERM)
    assert rc == 143, err
    assert os.listdir(tmp_path) == []        # not even the csv directory it made (it did not exist before)


def test_steps_csv_interrupted_keeps_a_directory_that_existed(tmp_path, big_file):
    (tmp_path / "csv").mkdir()
    rc, err = _run_and_signal(["steps", big_file, "-o", str(tmp_path / "s.npz"), "--csv", str(tmp_path / "csv"),
                               "-q"], tmp_path, signal.SIGTERM)
    assert rc == 143, err
    assert os.listdir(tmp_path) == ["csv"] and os.listdir(tmp_path / "csv") == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_estimate_interrupted_exits_128_plus_signal(tmp_path, long_file, sig):
    rc, err = _run_and_signal(["estimate", long_file, "--per-line", str(tmp_path / "l.csv")], tmp_path, sig,
                              wait_for_temp=False)
    assert rc == 128 + sig, err
    assert os.listdir(tmp_path) == []


@pytest.mark.slow
@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_steps_on_the_50mb_file(tmp_path, sig):
    src = shared_path("gcode", "prusaslicer25_plate150_gyroid_big.gcode")
    rc, err = _run_and_signal(["steps", str(src), "-o", str(tmp_path / "s.npz"), "-q"], tmp_path, sig)
    assert rc == 128 + sig, err
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- in-process pieces
def test_atomic_output_interrupted_by_sigterm_in_process(tmp_path):
    target = tmp_path / "out.txt"
    restore = signals.install()
    try:
        with pytest.raises(signals.Terminated) as err:
            with output.atomic_output(str(target)) as fh:
                fh.write("half")
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):        # the handler runs at the next bytecode boundary
                    time.sleep(0.001)
        assert signals.exit_status(err.value) == 143 and err.value.reason == "terminated by SIGTERM"
    finally:
        restore()
    assert os.listdir(tmp_path) == []
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL      # handlers restored after the command


def test_a_swallowed_termination_is_raised_again():
    """Python code called back from C (llvmlite's ctypes callbacks during numba compilation) prints and
    drops the exception a handler raises: the command must not run on."""
    restore = signals.install()
    try:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.5)
        except signals.Terminated:
            pass                                  # lost, as in a ctypes callback
        with pytest.raises(signals.Terminated) as err:
            time.sleep(10 * signals.RERAISE_S)
        assert err.value.signum == signal.SIGTERM
        signals.caught()
        os.kill(os.getpid(), signal.SIGHUP)       # once caught, later signals are ignored
        time.sleep(0.05)
    finally:
        restore()


def test_a_signal_inside_the_jit_waits_until_the_main_thread_is_out_of_it():
    """An exception raised inside numba or llvmlite (compiling or loading a kernel) can leave the JIT half-built
    and crash the process on its way out: the signal is held back there and raised as soon as the main thread is
    back in gcodeplan's code, well before the once-a-second re-raise."""
    jit_globals = {"__name__": "numba.core.fake_compiler", "time": time, "os": os, "signal": signal}
    exec("def compile_kernel():\n"
         "    os.kill(os.getpid(), signal.SIGTERM)\n"
         "    for _ in range(300):\n"
         "        time.sleep(0.001)\n"
         "    return 'compiled'\n", jit_globals)
    restore = signals.install()
    try:
        with pytest.raises(signals.Terminated) as err:
            assert jit_globals["compile_kernel"]() == "compiled"      # not interrupted inside
            t_out = time.monotonic()
            while time.monotonic() - t_out < 10 * signals.RERAISE_S:
                time.sleep(0.001)         # (interrupt_main lands between bytecodes, not inside one long sleep)
        waited_s = time.monotonic() - t_out
        assert err.value.signum == signal.SIGTERM
        assert waited_s < signals.RERAISE_S / 2, waited_s
        signals.caught()
    finally:
        restore()


def test_a_signal_after_the_command_ended_does_not_kill_its_process(tmp_path):
    """The gcodeplan command's process, its work written, exits next: restore(process_ends=True) sweeps and
    leaves the handlers in place, ignoring, so a SIGHUP arriving in that window leaves the exit status 0 (it once
    came as "killed by SIGHUP" in tools/fuzz.py's signal round, after the estimate had finished)."""
    before = {sig: signal.getsignal(sig) for sig in signals.HANDLED}
    restore = signals.install()
    fd, name = output.make_temp_file(tmp_path / "x.bin")
    os.close(fd)
    try:
        restore(process_ends=True)
        assert os.listdir(tmp_path) == []                      # swept all the same
        os.kill(os.getpid(), signal.SIGHUP)                    # the default action would end this process
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.2:
            time.sleep(0.001)                                  # the handler runs (and ignores it) here
        assert signal.getsignal(signal.SIGHUP) is not signal.SIG_DFL
    finally:
        for sig, old in before.items():
            signal.signal(sig, old)


def test_registered_temporaries_are_swept_on_the_way_out(tmp_path):
    restore = signals.install()
    fd, name = output.make_temp_file(tmp_path / "x.bin")
    os.close(fd)
    assert os.path.exists(name) and os.path.basename(name).startswith(".x.bin.gcodeplan-")
    restore()
    assert os.listdir(tmp_path) == []


def test_stale_temporaries_of_a_dead_process_are_removed_live_ones_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".r.html.gcodeplan-{dead}-abc.tmp"
    stale_dir = tmp_path / f".r.html.gcodeplan-{dead}-def.spool"
    live = tmp_path / f".r.html.gcodeplan-{os.getpid()}-ghi.tmp"
    other = tmp_path / ".other.gcodeplan-1-x.tmp"
    for p in (stale, live, other):
        p.write_text("x")
    stale_dir.mkdir()
    (stale_dir / "0000.raw").write_bytes(b"\0" * 10)
    output.atomic_write_text(str(tmp_path / "r.html"), "<html></html>")
    assert sorted(os.listdir(tmp_path)) == sorted([live.name, other.name, "r.html"])


# ----------------------------------------------------------------------------- inherited dispositions
def _ignoring(sig):
    return lambda: signal.signal(sig, signal.SIG_IGN)


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT], ids=lambda s: signal.Signals(s).name)
def test_a_signal_inherited_as_ignored_stays_ignored(tmp_path, long_file, sig):
    """`nohup gcodeplan …` (SIGHUP ignored) and a script's background job (SIGINT ignored) run on."""
    proc = subprocess.Popen([sys.executable, "-m", "gcodeplan.cli", "estimate", long_file, "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_ignoring(sig))
    try:
        t0 = time.monotonic()
        while not _handles_sigterm(proc.pid):          # gcodeplan's handlers are in place
            assert proc.poll() is None and time.monotonic() - t0 < 120, proc.stderr.read()
            time.sleep(0.02)
        time.sleep(0.3)
        assert proc.poll() is None, "finished before the signal"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert json.loads(out)["moves"] > 1_000_000


def test_an_error_after_a_signal_is_the_signal(tmp_path, monkeypatch, capsys):
    """A handler's exception raised inside a callback from C comes back as a SystemError (numba's compiler):
    exit 128 + n with the one-line message, not an internal error with a traceback."""
    mod = tmp_path / "gp_fake_cmd.py"
    mod.write_text(
        "import os, signal, time\n"
        "def add_arguments(p):\n    pass\n"
        "def run(args):\n"
        "    try:\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        for _ in range(2000):\n            time.sleep(0.001)\n"
        "    except KeyboardInterrupt as err:\n"
        "        raise SystemError('<built-in function x> returned a result with an exception set') from err\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "fake", ("gp_fake_cmd", "test"))
    rc = cli.main(["fake"])
    err = capsys.readouterr().err
    assert rc == 143 and err == "gcodeplan: terminated by SIGTERM\n", err


def test_a_signal_inside_a_ctypes_callback_is_one_line(tmp_path):
    """The print-and-ignore of an exception in a ctypes callback (how llvmlite calls back during numba's
    compilation) adds no 'Exception ignored' traceback; the re-raise ends the command with 143."""
    script = tmp_path / "cb.py"
    script.write_text(
        "import ctypes, os, signal, sys, time\n"
        "from gcodeplan import cli\n"
        "class Cmd:\n"
        "    @staticmethod\n"
        "    def add_arguments(p): pass\n"
        "    @staticmethod\n"
        "    def run(args):\n"
        "        libc = ctypes.CDLL(None)\n"
        "        CMP = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int))\n"
        "        sent = []\n"
        "        def cmp(a, b):\n"
        "            if not sent:\n"
        "                sent.append(1); os.kill(os.getpid(), signal.SIGTERM)\n"
        "                for _ in range(100): time.sleep(0.001)\n"
        "            return a[0] - b[0]\n"
        "        arr = (ctypes.c_int * 4)(3, 1, 2, 0)\n"
        "        libc.qsort(arr, 4, ctypes.sizeof(ctypes.c_int), CMP(cmp))\n"
        "        for _ in range(10000): time.sleep(0.001)\n"
        "        return 0\n"
        "sys.modules['gp_cb_cmd'] = Cmd\n"
        "cli.COMMANDS['cb'] = ('gp_cb_cmd', 'test')\n"
        "sys.exit(cli.main(['cb']))\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 143 and proc.stderr == "gcodeplan: terminated by SIGTERM\n", proc.stderr


# ----------------------------------------------------------------------------- estimate --jobs
def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(x) for x in fh.read().split()]
    except OSError:
        return []


def test_a_dead_jobs_worker_is_reported_not_waited_for(tmp_path, long_file):
    proc = subprocess.Popen([sys.executable, "-m", "gcodeplan.cli", "estimate", "--jobs", "2", long_file, long_file],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while len(_children(proc.pid)) < 2:
            assert proc.poll() is None and time.monotonic() - t0 < 120, proc.stderr.read()
            time.sleep(0.02)
        time.sleep(0.5)
        assert proc.poll() is None, "finished before the kill"
        workers = _children(proc.pid)
        os.kill(workers[0], signal.SIGKILL)                 # as the out-of-memory killer does
        out, err = proc.communicate(timeout=90)         # before: waited forever
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and long_file in lines[0] and "died" in lines[0] and "SIGKILL" in lines[0], err
    time.sleep(0.5)
    assert not any(os.path.exists(f"/proc/{pid}") for pid in workers)     # the other one was stopped


def test_a_signal_wrapped_by_an_import_is_still_the_signal(monkeypatch, capsys):
    """The fuzzer's SIGHUP at 0.65 s landed while `plot` imported matplotlib: Python wrapped the handler's
    exception into a RuntimeError (raised in a class body's __set_name__) before the command ran, and the process
    died with a traceback and status 1. It is the signal: one line, 128 + 1."""
    import signal as sig
    import time as _time

    from gcodeplan import cli

    def build_parser(argv):
        try:
            os.kill(os.getpid(), sig.SIGHUP)
            _time.sleep(5)                     # the handler raises in here
        except KeyboardInterrupt as err:
            raise RuntimeError("Error calling __set_name__ on '_axis_method_wrapper' instance") from err
        raise AssertionError("no signal arrived")

    monkeypatch.setattr(cli, "build_parser", build_parser)
    assert cli.main(["plot", "layers", "x.gcode"]) == 128 + sig.SIGHUP
    assert capsys.readouterr().err.strip() == "gcodeplan: terminated by SIGHUP"
