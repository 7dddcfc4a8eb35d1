"""What an output path names decides how it is written (report/output.py): ``-`` is standard output, a
device or FIFO is a stream (never replaced), a symbolic link is followed (the link stays), a full standard
output is one line and exit 2, and what a failed run made (an empty ``--csv`` directory) is removed.

Every test works inside its own temporary directory with stand-ins (a link to /dev/null, a FIFO, a character
device made with mknod): nothing outside it can be replaced even by a wrong implementation.
"""
from __future__ import annotations

import io
import os
import pty
import stat
import subprocess
import sys
import threading

import numpy as np
import pytest

from gcodeplan.errors import GcodeplanError
from gcodeplan.report import output

PROGRAM = "G28\nG1 X10 Y10 F3000\nG1 X20 E1\nG1 X30 Y5 E2\n"


@pytest.fixture
def gcode(tmp_path):
    p = tmp_path / "a.gcode"
    p.write_text(PROGRAM)
    return p


def cli(*argv, cwd, stdout=subprocess.PIPE, stdin=None, input=None, env=None, timeout=300):
    """The real command, as a user runs it."""
    return subprocess.run([sys.executable, "-m", "gcodeplan.cli", *map(str, argv)], cwd=cwd, stdout=stdout,
                          stderr=subprocess.PIPE, stdin=stdin, input=input, env=env, timeout=timeout)


def one_line_error(proc, *words) -> str:
    err = proc.stderr.decode()
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gcodeplan: "), err
    for w in words:
        assert w in lines[0], err
    return lines[0]


def make_char_device(path, minor: int) -> None:
    """A character device node in a temporary directory (1, 3: like /dev/null; 1, 7: like /dev/full)."""
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    except PermissionError:
        pytest.skip("mknod needs root")


# ----------------------------------------------------------------------------- '-' is standard output
@pytest.mark.parametrize("command", [["post-process", "{f}", "-o", "-"], ["dump-moves", "{f}", "-o", "-"],
                                     ["report", "{f}", "-o", "-", "--slowest", "0"],
                                     ["view", "{f}", "-o", "-"], ["estimate", "{f}", "--per-line", "-"]],
                         ids=lambda c: c[0])
def test_dash_is_standard_output_and_no_file_named_dash(tmp_path, gcode, command):
    run = tmp_path / "run"
    run.mkdir()
    proc = cli(*[a.format(f=gcode) for a in command], cwd=run)
    assert proc.returncode == 0, proc.stderr.decode()
    assert os.listdir(run) == []                      # no file called '-' (nor anything else)
    out = proc.stdout.decode()
    first = {"post-process": "M73 P0", "dump-moves": "line,kind,", "report": "<!DOCTYPE html>",
             "view": "<!DOCTYPE html>", "estimate": "source_line,end_time_s"}[command[0]]
    assert out.startswith(first), out[:200]
    if command[0] == "post-process":
        assert out.count("M73 P") >= 2 and gcode.read_text() == PROGRAM     # the input untouched
    if command[0] == "estimate":                                            # the CSV alone on stdout
        rows = [line.split(",") for line in out.splitlines()[1:]]
        assert [int(n) for n, _ in rows] == [2, 3, 4] and all(float(t) > 0 for _, t in rows)
        assert "total time" in proc.stderr.decode()


def test_npz_and_png_to_standard_output_pipe(tmp_path, gcode):
    proc = cli("steps", gcode, "-o", "-", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr.decode()
    data = np.load(io.BytesIO(proc.stdout))
    assert data["x"].size == 30 * 80 and "x: " in proc.stderr.decode()   # the summary went to stderr
    proc = cli("plot", gcode, "-o", "-", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.startswith(b"\x89PNG"), proc.stderr.decode()
    assert sorted(os.listdir(tmp_path)) == ["a.gcode"]


@pytest.mark.parametrize("command", [["plot", "{f}", "-o", "-"], ["steps", "{f}", "-o", "-"],
                                     ["profile", "--distance", "10", "--v-max", "100", "--a-max", "1000",
                                      "--plot", "-"]], ids=lambda c: c[0])
def test_binary_output_to_a_terminal_is_refused(tmp_path, gcode, command):
    master, slave = pty.openpty()
    try:
        proc = cli(*[a.format(f=gcode) for a in command], cwd=tmp_path, stdout=slave)
    finally:
        os.close(slave)
        os.close(master)
    assert proc.returncode == 2
    one_line_error(proc, "terminal")
    assert sorted(os.listdir(tmp_path)) == ["a.gcode"]


# ----------------------------------------------------------------------------- devices, FIFOs, links
def test_symlink_to_a_device_stays_a_link(tmp_path, gcode):
    link = tmp_path / "null"
    os.symlink(os.devnull, link)
    for argv in (["post-process", gcode, "-o", link], ["dump-moves", gcode, "-o", link],
                 ["steps", gcode, "-o", link, "-q"], ["plot", gcode, "-o", link], ["view", gcode, "-o", link]):
        proc = cli(*argv, cwd=tmp_path)
        assert proc.returncode == 0, (argv, proc.stderr.decode())
        assert os.path.islink(link) and os.readlink(link) == os.devnull, argv
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "null"]


def test_character_device_is_written_not_replaced(tmp_path, gcode):
    dev = tmp_path / "devnull"
    make_char_device(dev, 3)
    for argv in (["post-process", gcode, "-o", dev], ["report", gcode, "-o", dev, "--slowest", "0"],
                 ["estimate", gcode, "--per-line", dev]):
        proc = cli(*argv, cwd=tmp_path)
        assert proc.returncode == 0, (argv, proc.stderr.decode())
        assert stat.S_ISCHR(os.lstat(dev).st_mode), argv
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "devnull"]


def test_full_device_is_one_line_and_stays(tmp_path, gcode):
    dev = tmp_path / "full"
    make_char_device(dev, 7)
    for argv in (["post-process", gcode, "-o", dev], ["steps", gcode, "-o", dev, "-q"],
                 ["dump-moves", gcode, "-o", dev]):
        proc = cli(*argv, cwd=tmp_path)
        assert proc.returncode == 2, (argv, proc.stderr.decode())
        one_line_error(proc, str(dev), "No space left on device")
        assert stat.S_ISCHR(os.lstat(dev).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "full"]


def test_fifo_is_written_as_a_stream(tmp_path, gcode):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    proc = cli("post-process", gcode, "-o", fifo, cwd=tmp_path, timeout=120)
    reader.join(60)
    assert proc.returncode == 0, proc.stderr.decode()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert got and got[0].startswith(b"M73 P0") and b"M73 P100" in got[0]
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "pipe"]


def test_in_place_on_a_symlink_rewrites_the_target_and_keeps_the_link(tmp_path, gcode):
    real = tmp_path / "store" / "real.gcode"
    real.parent.mkdir()
    real.write_text(PROGRAM)
    os.chmod(real, 0o640)
    link = tmp_path / "print.gcode"
    os.symlink(os.path.join("store", "real.gcode"), link)
    proc = cli("post-process", link, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr.decode()
    assert os.path.islink(link) and os.readlink(link) == os.path.join("store", "real.gcode")
    assert "M73 P100" in real.read_text()
    assert stat.S_IMODE(os.stat(real).st_mode) == 0o640              # the target's permissions kept
    assert sorted(os.listdir(real.parent)) == ["real.gcode"]         # no temporary left beside it


def test_output_through_a_dangling_link_creates_its_target(tmp_path, gcode):
    link = tmp_path / "out.csv"
    os.symlink("made.csv", link)
    proc = cli("dump-moves", gcode, "-o", link, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr.decode()
    assert os.path.islink(link) and (tmp_path / "made.csv").read_text().startswith("line,kind,")


def test_resolve_output_kinds(tmp_path):
    assert output.resolve_output("-").kind == "stdout"
    assert output.resolve_output(os.devnull).kind == "stream"
    f = tmp_path / "f.txt"
    assert output.resolve_output(f).kind == "file"
    os.symlink("f.txt", tmp_path / "l.txt")
    t = output.resolve_output(tmp_path / "l.txt")
    assert t.kind == "file" and t.real == str(f)
    with pytest.raises(GcodeplanError, match="is a directory"):
        output.resolve_output(tmp_path)
    with pytest.raises(GcodeplanError, match="no such directory"):
        output.resolve_output(tmp_path / "nope" / "x.html")


def test_atomic_output_follows_a_link_in_process(tmp_path):
    real = tmp_path / "r.html"
    real.write_text("old")
    os.chmod(real, 0o600)
    os.symlink("r.html", tmp_path / "l.html")
    output.atomic_write_text(str(tmp_path / "l.html"), "new")
    assert os.path.islink(tmp_path / "l.html") and real.read_text() == "new"
    assert stat.S_IMODE(os.stat(real).st_mode) == 0o600


# ----------------------------------------------------------------------------- a full standard output
@pytest.mark.parametrize("argv", [["estimate", "{f}"], ["estimate", "{f}", "--json"], ["parse", "{f}"],
                                  ["parse", "{f}", "--json"], ["estimate", "{f}", "{f}", "--jobs", "2"],
                                  ["dump-moves", "{f}", "-o", "-"]], ids=lambda a: " ".join(a[:1] + a[2:]))
def test_full_standard_output_is_one_line_exit_2(tmp_path, gcode, argv):
    with open(os.devnull if not os.path.exists("/dev/full") else "/dev/full", "wb") as full:
        proc = cli(*[a.format(f=gcode) for a in argv], cwd=tmp_path, stdout=full)
    assert proc.returncode == 2, proc.stderr.decode()
    one_line_error(proc, "standard output", "No space left on device")


def test_closed_pipe_is_quiet(tmp_path, gcode):
    proc = subprocess.run(f"{sys.executable} -m gcodeplan.cli dump-moves {gcode} -o - | head -c 10 >/dev/null",
                          shell=True, cwd=tmp_path, stderr=subprocess.PIPE, timeout=300)
    assert "Traceback" not in proc.stderr.decode() and "Exception" not in proc.stderr.decode()


# ----------------------------------------------------------------------------- default names for '-'
@pytest.mark.parametrize("command,name", [("report", "stdin.html"), ("view", "stdin.view.html")])
def test_default_output_for_standard_input_is_named_stdin(tmp_path, command, name):
    argv = [command, "-"] + (["--slowest", "0"] if command == "report" else [])
    proc = cli(*argv, cwd=tmp_path, input=PROGRAM.encode())
    assert proc.returncode == 0, proc.stderr.decode()
    assert os.listdir(tmp_path) == [name] and proc.stdout.decode().strip() == name


def test_default_output_rule():
    assert output.default_output("-", ".html") == "stdin.html"
    assert output.default_output("/dev/fd/63", ".view.html") == "stdin.view.html"
    assert output.default_output("dir/a.gcode", "_velocity.png") == "dir/a_velocity.png"


# ----------------------------------------------------------------------------- what a failed run made
def test_csv_dir_made_by_a_failed_steps_run_is_removed(tmp_path, gcode):
    dev = tmp_path / "full"
    make_char_device(dev, 7)
    proc = cli("steps", gcode, "-o", dev, "--csv", tmp_path / "csv" / "deeper", "-q", cwd=tmp_path)
    assert proc.returncode == 2
    one_line_error(proc, "No space left on device")
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "full"]       # csv/ and csv/deeper/ gone again


def test_csv_dir_that_existed_is_kept(tmp_path, gcode):
    dev = tmp_path / "full"
    make_char_device(dev, 7)
    (tmp_path / "csv").mkdir()
    proc = cli("steps", gcode, "-o", dev, "--csv", tmp_path / "csv", "-q", cwd=tmp_path)
    assert proc.returncode == 2
    assert sorted(os.listdir(tmp_path)) == ["a.gcode", "csv", "full"] and os.listdir(tmp_path / "csv") == []


def test_view_of_standard_input_with_a_full_tmpdir(tmp_path):
    """$TMPDIR with a little room (tempfile's own probe passes) but not enough for the copy of stdin."""
    small = tmp_path / "small"
    small.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(small)],
                      capture_output=True).returncode != 0:
        pytest.skip("needs a small tmpfs (root)")
    try:
        program = PROGRAM + "G1 X1 Y1 F6000\nG1 X100 Y100\n" * 20000        # ~0.6 MB of standard input
        env = dict(os.environ, TMPDIR=str(small))
        proc = cli("view", "-", "-o", tmp_path / "v.html", cwd=tmp_path, input=program.encode(), env=env)
        assert proc.returncode == 2
        one_line_error(proc, "<stdin>", "No space left on device")   # the spool (read once) names its input
        assert not (tmp_path / "v.html").exists() and os.listdir(small) == []
    finally:
        subprocess.run(["umount", str(small)], capture_output=True)


# ----------------------------------------------------------------------------- /dev/stdout and its kin
def test_a_link_to_proc_self_fd_1_is_standard_output(tmp_path, gcode):
    """What /dev/stdout is (a link to /proc/self/fd/1), made inside the temporary directory: the output goes down
    the pipe and the link stays (it was replaced by a regular file)."""
    if not os.path.exists("/proc/self/fd/1"):
        pytest.skip("needs /proc")
    link = tmp_path / "stdout"
    os.symlink("/proc/self/fd/1", link)
    proc = cli("dump-moves", gcode, "-o", link, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr.decode()
    assert proc.stdout.decode().startswith("line,kind,")
    assert os.path.islink(link) and os.readlink(link) == "/proc/self/fd/1"


def test_output_naming_the_file_standard_output_is_goes_down_standard_output(tmp_path, gcode):
    """`gcodeplan post-process a.gcode -o /dev/stdout >> log`: the same file, appended through the descriptor the
    shell opened, not replaced by a new file behind the shell's back."""
    log = tmp_path / "log.txt"
    log.write_bytes(b"earlier\n")
    inode = os.stat(log).st_ino
    with open(log, "ab") as out:
        proc = cli("post-process", gcode, "-o", log, "-q", cwd=tmp_path, stdout=out)
    assert proc.returncode == 0, proc.stderr.decode()
    text = log.read_text()
    assert os.stat(log).st_ino == inode and text.startswith("earlier\nM73 P0") and "M73 P100" in text
