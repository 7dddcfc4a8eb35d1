"""The command line's options: no abbreviations, a command's own usage for an unknown option, and a note
when a file moves nothing (0 s is then no estimate of anything)."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from gcodeplan import cli

COMMANDS = ["estimate", "parse", "steps", "plot", "report", "view", "post-process", "dump-moves", "profile"]


def run(*argv, cwd=None, input=None):
    return subprocess.run([sys.executable, "-m", "gcodeplan.cli", *map(str, argv)], cwd=cwd, input=input,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("argv", [
    ["estimate", "{f}", "--jso"], ["parse", "{f}", "--jso"], ["steps", "{f}", "-o", "{o}.npz", "--forma", "compact"],
    ["plot", "{f}", "-o", "{o}.png", "--wha", "path"], ["report", "{f}", "-o", "{o}.html", "--slowes", "0"],
    ["view", "{f}", "-o", "{o}.html", "--quie"], ["post-process", "{f}", "-o", "{o}.gcode", "--no-m7"],
    ["dump-moves", "{f}", "-o", "{o}.csv", "--exclude-objec", "a"],
    ["profile", "--distance", "10", "--v-max", "100", "--a-max", "1000", "--v-star", "1"]], ids=lambda a: a[0])
def test_no_command_accepts_an_abbreviated_option(tmp_path, capsys, argv):
    g = tmp_path / "a.gcode"
    g.write_text("G1 X10 F3000\n")
    cut = next(a for a in argv if a.startswith("--") and a not in ("--distance", "--v-max", "--a-max"))
    with pytest.raises(SystemExit) as exit_:        # argparse's usage error
        cli.main([a.format(f=g, o=tmp_path / "out") for a in argv])
    out, err = capsys.readouterr()
    assert exit_.value.code == 2
    assert f"unrecognized arguments: {cut}" in err and out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gcode"]       # nothing ran


def test_parsers_refuse_abbreviations():
    for command in COMMANDS:
        parser = cli.build_parser([command])
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
        assert parser.allow_abbrev is False and sub.allow_abbrev is False, command


def test_machin_is_an_error_naming_it_with_the_commands_usage(tmp_path):
    g = tmp_path / "a.gcode"
    g.write_text("G1 X10 F3000\n")
    proc = run("estimate", g, "--machin", "grbl")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith("usage: gcodeplan estimate ")
    assert proc.stderr.strip().splitlines()[-1] == "gcodeplan estimate: error: unrecognized arguments: --machin grbl"


@pytest.mark.parametrize("command", ["steps", "view", "dump-moves"])
def test_unknown_option_prints_the_commands_usage(tmp_path, command):
    proc = run(command, "x.gcode", "-o", tmp_path / "x.out", "--bogus")
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"usage: gcodeplan {command} ")
    assert "unrecognized arguments: --bogus" in proc.stderr


@pytest.mark.parametrize("text,note", [("", "is empty"), ("; only a comment\nM104 S200\n", "has no motion (2 lines")])
def test_nothing_moved_is_said(tmp_path, text, note):
    g = tmp_path / "n.gcode"
    g.write_text(text)
    proc = run("estimate", g)
    assert proc.returncode == 0 and "(0.000 s)" in proc.stdout
    notes = [ln for ln in proc.stderr.splitlines() if ln.startswith("gcodeplan: note:")]
    assert len(notes) == 1 and str(g) in notes[0] and note in notes[0], proc.stderr
    # --json: the same keys as for a file that moves; the note only on stderr
    js = run("estimate", g, "--json")
    moving = tmp_path / "m.gcode"
    moving.write_text("G1 X10 F3000\n")
    ref = json.loads(run("estimate", moving, "--json").stdout)
    d = json.loads(js.stdout)
    assert d["total_time_s"] == 0.0 and set(d) == set(ref)
    assert note in js.stderr


def test_a_file_that_moves_has_no_note(tmp_path):
    g = tmp_path / "m.gcode"
    g.write_text("G1 X10 F3000\n")
    proc = run("estimate", g)
    assert proc.returncode == 0 and proc.stderr == ""


def test_many_files_note_each_that_moves_nothing(tmp_path):
    (tmp_path / "e.gcode").write_text("")
    (tmp_path / "m.gcode").write_text("G1 X10 F3000\n")
    proc = run("estimate", "e.gcode", "m.gcode", cwd=tmp_path)
    assert proc.returncode == 0
    assert proc.stderr.strip() == "gcodeplan: note: e.gcode is empty: its time is 0 s"
