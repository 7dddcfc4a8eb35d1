"""Absurd limits on the firmware models (marlin-2.1.2, grbl-1.1): a clear error naming the file and line, or the
firmware's own reading of the number, never a traceback, a numpy warning, or a negative or infinite time.

G-code has no exponent (``M204 P1e-320`` is P1 then E-320), so absurd magnitudes are written out as decimals:
``TINY`` is under the smallest float32 (0 in Marlin's and grbl's floats), ``HUGE`` is 1e308 (inf in them).
"""
import math
import warnings

import pytest

import gcodeplan as gp
from gcodeplan.errors import ConfigError, GcodeError

TINY = "0." + "0" * 319 + "1"          # 1e-320
TINY46 = "0." + "0" * 45 + "1"         # 1e-46: a double, 0 as a float32
HUGE = "1" + "0" * 308                 # 1e308
MOVES = "G1 X10 Y10 F3000\nG1 X20 Y5 E1 F3000\nG1 Z1 F600\n"


def _estimate(tmp_path, line, machine="marlin"):
    p = tmp_path / "a.gcode"
    p.write_text("G28\n" + line + "\n" + MOVES)
    with warnings.catch_warnings():
        warnings.simplefilter("error")            # no numpy overflow warnings either
        return gp.estimate(str(p), gp.load_machine(machine) if isinstance(machine, str) else machine)


@pytest.mark.parametrize("line, what, at", [
    ("SET_VELOCITY_LIMIT ACCEL=1e-320", "acceleration", 3),     # tools/fuzz.py: a ZeroDivisionError before
    ("SET_VELOCITY_LIMIT ACCEL=1e-46", "acceleration", 3),
    (f"M204 P{TINY}", "acceleration", 4),                         # the first printing move (E) uses P
    (f"M204 S{TINY46}", "acceleration", 3),
    (f"M204 T{TINY}", "acceleration", 3),
    ("M201 X0.5", "axis acceleration limit (M201)", 3),         # Marlin keeps M201 as whole mm/s²: 0
    (f"M201 Z{TINY}", "axis acceleration limit (M201)", 5),
    (f"M203 X{TINY}", "axis speed limit (M203)", 3),
    (f"M220 S{TINY}", "feed rate", 3),
])
def test_marlin_zero_in_its_own_numbers_is_an_error_naming_the_line(tmp_path, line, what, at):
    with pytest.raises(GcodeError) as err:
        _estimate(tmp_path, line)
    assert err.value.line == at and err.value.file.endswith("a.gcode")
    assert what in str(err.value) and "0 in Marlin's own numbers" in str(err.value)


@pytest.mark.parametrize("line", ["SET_VELOCITY_LIMIT ACCEL=1e308", f"M201 X{HUGE} Y{HUGE}", f"M203 X{HUGE}",
                                  f"M204 P{HUGE} T{HUGE}", f"M205 X{HUGE} Y{HUGE}", f"M205 J{HUGE}",
                                  "SET_VELOCITY_LIMIT ACCEL=1e39", f"M201 E{HUGE}"])
def test_marlin_huge_limits_are_its_float_inf_and_only_speed_up(tmp_path, line):
    base = _estimate(tmp_path, "M400").time.total_time_s
    t = _estimate(tmp_path, line).time.total_time_s
    assert math.isfinite(t) and 0 < t <= base + 1e-9
    if line.startswith(("SET_VELOCITY", "M204")):
        assert t < base                               # the moves' acceleration is then capped by M201 alone


_SVL = [("SET_VELOCITY_LIMIT ACCEL=0", "ACCEL must be > 0"), ("SET_VELOCITY_LIMIT ACCEL=-1", "ACCEL must be > 0"),
        ("SET_VELOCITY_LIMIT ACCEL=nan", "out of range"), ("SET_VELOCITY_LIMIT ACCEL=inf", "out of range"),
        ("SET_VELOCITY_LIMIT VELOCITY=0", "VELOCITY must be > 0")]
_M = [("M201 X0", "M201 X must be > 0"), ("M201 X-5", "M201 X must be > 0"), ("M204 P0", "M204 P must be > 0"),
      ("M205 X-1", "M205 X must be >= 0"), ("M203 X-1", "M203 X must be > 0"), ("M220 S0", "M220 S must be > 0")]


@pytest.mark.parametrize("line, match, machine", [(a, b, "marlin") for a, b in _SVL + _M]
                         + [(a, b, "klipper") for a, b in _SVL])      # Klipper's flavor does not apply M201 …
def test_zero_negative_nan_inf_are_errors_naming_the_line(tmp_path, line, match, machine):
    with pytest.raises(GcodeError, match=match) as err:
        _estimate(tmp_path, line, machine)
    assert err.value.line == 2


def test_a_machine_files_sub_millimetre_m201_is_refused_at_the_move(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text('base = "marlin"\n[axis.z]\nmax_accel = 0.5\n')
    with pytest.raises(GcodeError, match="M201") as err:
        _estimate(tmp_path, "M400", str(m))
    assert err.value.line == 5                        # the Z move; X/Y moves are fine


def test_grbl_ignores_klippers_velocity_limit_and_says_so(tmp_path):
    p = tmp_path / "a.gcode"
    p.write_text("G21 G90\nSET_VELOCITY_LIMIT ACCEL=1e-320\nG1 X10 Y10 F3000\nG1 X20 Y5 F3000\n")
    q = tmp_path / "b.gcode"
    q.write_text("G21 G90\nG1 X10 Y10 F3000\nG1 X20 Y5 F3000\n")
    est = gp.estimate(str(p), gp.load_machine("grbl"))
    assert est.time.total_time_s == gp.estimate(str(q), gp.load_machine("grbl")).time.total_time_s
    assert "SET_VELOCITY_LIMIT" in est.to_text()       # listed as not modelled, never silently dropped


def _grbl_settings(tmp_path, key, value):
    lines = ["$100=80.000", "$101=80.000", "$102=400.000", "$110=6000.000", "$111=6000.000", "$112=1200.000",
             "$120=500.000", "$121=500.000", "$122=100.000", "$11=0.010", "$12=0.002"]
    lines = [f"${key}={value}" if x.startswith(f"${key}=") else x for x in lines]
    p = tmp_path / "grbl.txt"
    p.write_text("\n".join(lines) + "\n")
    return p


@pytest.mark.parametrize("key, value, match", [
    (120, TINY, r"line 7: \$120 .* is 0 in grbl's float"), (100, TINY, r"line 1: \$100 .* is 0 in grbl's float"),
    (110, TINY, r"line 4: \$110 .* is 0 in grbl's float"), (120, HUGE, r"line 7: \$120=1000.* beyond grbl's float"),
    (100, HUGE, r"line 1: \$100=1000.* beyond grbl's float"), (12, HUGE, r"line 11: \$12=1000.* beyond grbl's float"),
    (120, "0", r"\$120 .* must be > 0"), (120, "-5", r"\$120 .* must be > 0"),
    (120, "0.0001", "max_accel: must be at least 0.001"),   # the bounds every machine file obeys
    (100, "0.00001", "steps_per_mm: must be a number of steps/mm from 0.001"),
])
def test_grbl_absurd_settings_name_the_file_and_line(tmp_path, key, value, match):
    p = _grbl_settings(tmp_path, key, value)
    with pytest.raises(ConfigError, match=match) as err:
        gp.load_machine(str(p))
    assert "grbl.txt" in str(err.value)


def test_cli_gives_one_line_never_a_traceback(tmp_path, capsys):
    from gcodeplan.cli import main

    for machine, line in (("marlin", "SET_VELOCITY_LIMIT ACCEL=1e-320"), ("marlin", "M201 X0.5"),
                          ("grbl", "SET_VELOCITY_LIMIT ACCEL=1e-320")):
        p = tmp_path / "a.gcode"
        p.write_text("G21\n" + line + "\nG1 X10 Y10 F3000\n")
        rc = main(["estimate", "--machine", machine, str(p)])
        err = capsys.readouterr().err
        assert "Traceback" not in err and "internal error" not in err
        if machine == "marlin":
            assert rc != 0 and err.strip().count("\n") == 0 and err.startswith(f"gcodeplan: {p}:3: ")
        else:
            assert rc == 0 and err == ""
