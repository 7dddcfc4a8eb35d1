"""An error quotes its input only in part (40 characters and '…'): a number of a million digits or a word of
thousands of letters cannot make the one-line error megabytes long. Each case's whole input text is known,
so the message must hold its first 40 characters, the ellipsis, and not the 41st on."""
from __future__ import annotations

import io
import subprocess
import sys

import pytest

from gcodeplan.errors import ConfigError, GcodeError, GcodeplanError
from gcodeplan.gcode import read_moves
from gcodeplan.machine import Machine

N = 100_000

CASES = {
    "axis number": (b"G28\nG1 X1" + b"0" * N + b"\n", "number out of range: X1" + "0" * 39 + "…"),
    "feed number": (b"G28\nG1 X1 F-" + b"1" * N + b"\n", "F-" + "1" * 39 + "…"),
    "long checksum": (b"N1 G1 X1*" + b"1" * N + b"\n", "malformed checksum"),      # int() refuses > 4300 digits
    "free-text command": (b"G28\nM" + b"1" * N + b" hello 1.2.3\n", "M" + "1" * 40 + "…"),
    "command number": (b"G28\nG" + b"1" * N + b" X1\n", "G" + "1" * 40 + "…"),
    "extended value": (b"G28\nSET_VELOCITY_LIMIT VELOCITY=" + b"1" * N + b"\n", "1" * 40 + "… is out of range"),
    "extended text": (b"G28\nSET_VELOCITY_LIMIT VELOCITY=x" + b"1" * N + b"\n", "x" + "1" * 40 + "…"),
    "command name": (b"G28\n" + b"A" * N + b"_X\n", "unknown command " + "A" * 40 + "…"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_errors_quote_at_most_40_characters_of_the_input(case):
    data, expected = CASES[case]
    with pytest.raises(GcodeError) as err:
        read_moves(io.BytesIO(data), Machine(flavor="klipper"), strict=True)
    msg = str(err.value)
    assert expected in msg
    assert len(msg) < 200
    assert err.value.file == "<stream>" and err.value.line in (1, 2)


def test_the_command_line_prints_one_short_line(tmp_path):
    p = tmp_path / "huge_number.gcode"
    p.write_bytes(b"G28\nG1 X" + b"9" * 1_000_000 + b"\n")          # a million digits (the line limit is 1 MiB)
    out = subprocess.run([sys.executable, "-m", "gcodeplan.cli", "estimate", str(p)], capture_output=True,
                         timeout=300)
    assert out.returncode == 2
    err = out.stderr.decode()
    assert err.count("\n") == 1 and len(err) < 300
    assert err.startswith(f"gcodeplan: {p}:2: number out of range: X" + "9" * 40 + "…")


def test_config_errors_are_clipped_too(tmp_path):
    from gcodeplan.config import load_machine

    p = tmp_path / "m.toml"
    p.write_text('kinematics = "' + "k" * 5000 + '"\n')
    with pytest.raises(ConfigError) as err:
        load_machine(str(p))
    msg = str(err.value).removeprefix(str(p) + ": ")       # the temporary directory's length is not ours
    assert len(msg) < 300 and "'" + "k" * 39 + "…" in msg


def test_paths_and_short_quotes_are_kept_whole():
    path = "/".join(["a_long_directory_name_of_a_user"] * 7) + "/part.view.html"     # a long relative path
    assert 200 < len(path) < 256
    err = GcodeplanError(f"cannot write {path}: no such directory")
    assert path in str(err)
    assert str(GcodeplanError("number out of range: X1e400")) == "number out of range: X1e400"
    long = GcodeplanError(" ".join(["G1"] * 2000))             # many short words: the whole is bounded
    assert len(str(long)) == 1001 and str(long).endswith("…")


# ------------------------------------------------------------------ [include] of a file that is not a config
def test_an_included_file_is_named_by_path_and_line_never_quoted(tmp_path):
    from gcodeplan.config import load_klipper_config

    secret = tmp_path / "shadow"
    secret.write_text("root:$6$SECRETHASH:20228:0:99999:7:::\n")
    cfg = tmp_path / "printer.cfg"
    cfg.write_text(f"[include {secret}]\n")
    with pytest.raises(ConfigError) as err:
        load_klipper_config(str(cfg))
    assert (err.value.file, err.value.line) == (str(secret), 1)
    assert "SECRETHASH" not in str(err.value) and "root" not in err.value.message
    secret.write_text("[stepper_x]\nstep_pin: PA1\n  \nnot a key value SECRETWORD\n")
    with pytest.raises(ConfigError) as err:
        load_klipper_config(str(cfg))
    assert (err.value.file, err.value.line) == (str(secret), 4) and "SECRETWORD" not in str(err.value)


def test_the_users_own_config_is_still_quoted(tmp_path):
    from gcodeplan.config import load_klipper_config

    cfg = tmp_path / "printer.cfg"
    cfg.write_text("max_velocity 300\n")
    with pytest.raises(ConfigError, match=r"printer\.cfg:1: 'max_velocity 300' is outside any \[section\]"):
        load_klipper_config(str(cfg))


def test_unknown_command_names_are_counted_under_40_characters():
    data = b"G28\n" + b"A" * N + b"_X\n" + b"A" * N + b"_Y\n"
    _, r = read_moves(io.BytesIO(data), Machine(flavor="klipper"))
    assert r.summary.unknown_commands == {"A" * 40 + "…": 2}
