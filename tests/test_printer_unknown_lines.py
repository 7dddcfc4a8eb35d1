"""A printer line led by a letter that is no command (a CNC post's O-words): unknown, reported, ignored.

Marlin's and Klipper's parsers take a line's first word as its command; ``O100 call`` is no command of theirs,
so the printer answers "Unknown command" and goes on. The truth here: the same program without those lines.
"""
from __future__ import annotations

import pytest

import gcodeplan as gp
from gcodeplan.errors import GcodeError

BODY = "G1 X1 F600\n{o1}G1 X20 Y5\n{o2}G1 X2 Y30\nM400\n"
O_LINES = ("O100 sub\n", "O100 call\n")


@pytest.mark.parametrize("machine", ["marlin", "klipper"])
def test_o_word_lines_are_unknown_commands_and_cost_nothing(tmp_path, machine):
    with_o = tmp_path / "with.gcode"
    with_o.write_text(BODY.format(o1=O_LINES[0], o2=O_LINES[1]))
    without = tmp_path / "without.gcode"
    without.write_text(BODY.format(o1="", o2=""))
    a = gp.estimate(str(with_o), machine=machine)
    b = gp.estimate(str(without), machine=machine)
    assert a.total_time_s == b.total_time_s > 0
    assert a.parse.unknown_commands == {"O100": 2}


def test_o_word_line_is_an_error_when_strict(tmp_path):
    f = tmp_path / "p.gcode"
    f.write_text(BODY.format(o1=O_LINES[0], o2=""))
    with pytest.raises(GcodeError, match=r"p\.gcode:2: unknown command O100"):
        gp.estimate(str(f), machine="marlin", strict=True)


def test_klipper_macro_starting_with_o_is_still_a_command(tmp_path):
    f = tmp_path / "p.gcode"
    f.write_text("OOZE_PURGE LENGTH=5\nG1 X10 F600\n")
    est = gp.estimate(str(f), machine="klipper")
    assert est.parse.unknown_commands == {"OOZE_PURGE": 1}
