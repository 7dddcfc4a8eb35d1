"""The four long functions split at their named parts (issue 22) keep their behaviour and stay split.

Truth: the line counts of tools/long_functions.py; LinuxCNC's o-word semantics worked by hand (every keyword
of convert_control_functions reaches its handler); Marlin's Configuration.h reader gives the warnings it
collected before an error too. (The split numba kernel against its Python source: tests/test_jit.py plans
every sample both ways, bit for bit.)
"""
from __future__ import annotations

import importlib.util
import sys
import warnings

import pytest

from conftest import REPO
from gcodeplan.errors import ConfigError
from gcodeplan.gcode import ngc
from gcodeplan.gcode.reader import read_moves
from gcodeplan.machine import Machine
from gcodeplan.schema import KIND_WAIT


def _long_functions():
    spec = importlib.util.spec_from_file_location("long_functions", REPO / "tools" / "long_functions.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["long_functions"] = mod
    spec.loader.exec_module(mod)
    return mod.long_functions()


@pytest.mark.parametrize("name", ["load_marlin_config", "Expander._control", "Rs274Commands._execute_cnc",
                                  "_move_limits_kernel"])
def test_the_split_functions_stay_under_100_lines(name):
    assert name not in [row[3] for row in _long_functions()]


def test_every_o_word_keyword_has_its_handler():
    # the keywords the reader accepts (LinuxCNC's read_o order); sub, endsub / return, call are dispatched
    # by _control itself, the others through convert_control_functions' table
    assert set(ngc._KEYWORDS) - {"sub", "endsub", "return", "call"} == set(ngc._O_HANDLERS)


def test_every_o_word_keyword_runs_as_linuxcnc_does():
    """A program using each keyword, by hand: o100 moves X by #1, o600 returns 5. X: 1 (call), 2 and 3
    (repeat 2), the while's passes 1 and 3 (pass 2 continues before its move, pass 4 breaks): 4, 5; the
    elseif branch: 6; the do-while's one pass: 7; #<_value> + 3 = 8."""
    prog = """G21 G90 G1 F600
o100 sub
  G1 X[#5420 + #1]
o100 endsub
o600 sub
  o600 return [5]
o600 endsub
o100 call [1]
o200 repeat [2]
  o100 call [1]
o200 endrepeat
#2 = 0
o300 while [#2 LT 10]
  #2 = [#2 + 1]
  o310 if [#2 EQ 2]
    o300 continue
  o310 endif
  o320 if [#2 EQ 4]
    o300 break
  o320 endif
  o100 call [1]
o300 endwhile
o400 if [0]
  G1 X100
o400 elseif [1]
  o100 call [1]
o400 else
  G1 X200
o400 endif
o500 do
  o100 call [1]
o500 while [0]
o600 call
G1 X[#<_value> + 3]
M2
"""
    rows, _ = read_moves(prog.splitlines(), Machine(name="mill", flavor="linuxcnc", max_velocity=100.0,
                                                    max_accel=1000.0))
    rows = rows[rows["kind"] != KIND_WAIT]
    assert [round(float(x), 9) for x in rows["x1"]] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]


def test_marlin_config_warnings_reach_the_caller_before_its_error(tmp_path):
    # DEFAULT_MAX_FEEDRATE missing (a warning, the preset's kept), then a bad DEFAULT_ACCELERATION (an error):
    # the warning is given, then the error names the file and line
    from gcodeplan.config.marlin_config import load_marlin_config

    (tmp_path / "Configuration.h").write_text(
        "#define CONFIGURATION_H_VERSION 02010204\n"
        "#define DEFAULT_AXIS_STEPS_PER_UNIT   { 80, 80, 400, 93 }\n"
        "#define DEFAULT_MAX_ACCELERATION      { 3000, 3000, 100, 10000 }\n"
        "#define DEFAULT_ACCELERATION          -5\n")
    (tmp_path / "Configuration_adv.h").write_text("#define CONFIGURATION_ADV_H_VERSION 02010204\n")
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        with pytest.raises(ConfigError, match=r"DEFAULT_ACCELERATION must be > 0") as err:
            load_marlin_config(str(tmp_path / "Configuration.h"))
    assert err.value.line == 4
    assert any("DEFAULT_MAX_FEEDRATE not defined" in str(w.message) for w in got)
