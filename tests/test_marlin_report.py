"""Marlin's M503 settings report as a machine (config/marlin_report.py): recognised by content by
``--machine FILE`` and ``gp.load_machine``; the reference build's report is the ``marlin`` preset and runs the
shared cube as Marlin 2.1.2.4 did (shared/reference/marlin); the junction-deviation and linear-advance builds'
reports give those variants' totals."""
from __future__ import annotations

import json
import warnings
from dataclasses import asdict

import pytest

import gcodeplan as gp
from gcodeplan.errors import ConfigError
from conftest import shared_path

# the reference build's M503 (shared/reference/marlin/README.md, "Machine"), as Marlin 2.1.2 prints it
REFERENCE_M503 = """\
echo:; Linear Units:
echo:  G21 ; (mm)
echo:; Temperature Units:
echo:  M149 C ; Units in Celsius
echo:; Filament settings (Disabled):
echo:  M200 S0 D1.75
echo:; Steps per unit:
echo:  M92 X100.00 Y100.00 Z400.00 E280.00
echo:; Max feedrates (units/s):
echo:  M203 X200.00 Y200.00 Z12.00 E120.00
echo:; Max Acceleration (units/s2):
echo:  M201 X1000.00 Y1000.00 Z200.00 E5000.00
echo:; Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):
echo:  M204 P1250.00 R1250.00 T1500.00
echo:; Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> X<max_x_jerk> Y<max_y_jerk> \
Z<max_z_jerk> E<max_e_jerk>):
echo:  M205 B20000.00 S0.00 T0.00 X8.00 Y8.00 Z0.40 E4.50
echo:; Home offset:
echo:  M206 X0.00 Y0.00 Z0.00
echo:; Hotend PID:
echo:  M301 P22.20 I1.08 D114.00
echo:; Z-Probe Offset:
echo:  M851 X0.00 Y0.00 Z-0.80 ; (mm)
echo:; Stepper driver current:
echo:  M906 X580 Y580 Z580
echo:  M906 T0 E650
echo:; Linear Advance:
echo:  M900 K0.00
ok
"""
CUBE = "prusaslicer25_cube20_marlin2"


def _report(tmp_path, text, name="m503.txt"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _same_machine(a, b):
    da, db = asdict(a), asdict(b)
    da.pop("name"), db.pop("name")
    assert da == db


@pytest.mark.parametrize("shape", ["echo", "bare", "octoprint"])
def test_the_reference_builds_m503_is_the_marlin_preset(tmp_path, shape):
    text = REFERENCE_M503
    if shape == "bare":                       # copied without Marlin's prefix
        text = "\n".join(line.removeprefix("echo:") for line in text.splitlines())
    elif shape == "octoprint":                # OctoPrint's terminal: Send:/Recv: lines, firmware messages
        text = "Send: M503\n" + "".join(f"Recv: {line}\n" for line in text.splitlines()) \
            + "Recv: echo:Active Extruder: 0\n"
    p = _report(tmp_path, text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")        # nothing in the reference's report is unmodelled
        m = gp.load_machine(str(p))
    assert m.firmware == "marlin-2.1.2" and m.junction_policy == "classic-jerk"
    _same_machine(m, gp.load_machine("marlin"))


def test_the_reference_builds_m503_runs_the_cube_as_marlin(tmp_path, capsys):
    times = json.loads(shared_path("reference", "marlin", "times.json").read_text())
    g = shared_path("gcode", CUBE + ".gcode")
    p = _report(tmp_path, REFERENCE_M503)
    est = gp.estimate(str(g), gp.load_machine(str(p)))
    assert est.time.total_time_s == pytest.approx(times[CUBE + ".gcode"]["total_time_s"], abs=1e-8)  # 1130.895265
    from gcodeplan.cli import main

    assert main(["estimate", "--machine", str(p), str(g)]) == 0
    assert "(1130.895 s)" in capsys.readouterr().out


@pytest.mark.parametrize("variant", ["jd", "la"])
def test_the_variant_builds_reports_give_their_totals(tmp_path, variant):
    """The junction-deviation build prints M205 J (and no X/Y/Z jerks); the linear-advance build M900 K0.05."""
    times = json.loads(shared_path("reference", "marlin", "variants", variant, "times.json").read_text())
    if variant == "jd":
        text = REFERENCE_M503.replace("M205 B20000.00 S0.00 T0.00 X8.00 Y8.00 Z0.40 E4.50",
                                      "M205 B20000.00 S0.00 T0.00 J0.013")
    else:
        text = REFERENCE_M503.replace("M900 K0.00", "M900 K0.05")
    m = gp.load_machine(str(_report(tmp_path, text)))
    if variant == "jd":
        assert (m.junction_policy, m.junction_deviation) == ("junction-deviation", 0.013)
    else:
        assert (m.junction_policy, m.pressure_advance) == ("classic-jerk", 0.05)
    est = gp.estimate(str(shared_path("gcode", CUBE + ".gcode")), m)
    assert est.time.total_time_s == pytest.approx(times[CUBE + ".gcode"]["total_time_s"], abs=1e-8)


def test_a_users_values_are_read(tmp_path):
    text = ("M92 X80.00 Y80.00 Z400.00 E93.00\nM203 X300.00 Y300.00 Z5.00 E25.00\n"
            "M201 X500.00 Y500.00 Z100.00 E5000.00\nM204 P500.00 R1000.00 T700.00\n"
            "M205 B20000.00 S0.00 T0.00 X10.00 Y10.00 Z0.30 E5.00\n")
    m = gp.load_machine(str(_report(tmp_path, text)))
    assert [m.axes[a].steps_per_mm for a in "xyze"] == [80, 80, 400, 93]
    assert [m.axes[a].max_velocity for a in "xyze"] == [300, 300, 5, 25]
    assert [m.axes[a].max_accel for a in "xyze"] == [500, 500, 100, 5000]
    assert [m.axes[a].jerk for a in "xyze"] == [10, 10, 0.3, 5]
    assert (m.accel_print, m.accel_retract, m.accel_travel, m.max_accel) == (500, 1000, 700, 500)
    # Marlin 1.x's M204 S: printing and travel
    m = gp.load_machine(str(_report(tmp_path, "M92 X80 Y80 Z400 E93\nM204 S900 R1000\n")))
    assert (m.accel_print, m.accel_travel, m.accel_retract) == (900, 900, 1000)


@pytest.mark.parametrize("line,match", [
    ("M593 X F40.00 D0.10", r"m503.txt:18: M593 \(input shaping"),
    ("M205 B10000.00", r"m503.txt:18: M205 B10000 \(minimum segment time"),
    ("M205 S5.00", r"m503.txt:18: M205 S5 \(minimum print feedrate\)"),
    ("M420 S1 Z10.00", r"m503.txt:18: M420 S1 \(bed levelling"),
    ("M425 F1.00 X0.10 Y0.10 Z0.00", r"m503.txt:18: M425 \(backlash"),
    ("M207 S3.00 W13.00 F2700.00 Z0.00", r"m503.txt:18: M207 \(firmware retraction"),
    ("M7219 X1", r"m503.txt:18: M7219: not a setting gcodeplan knows"),
    ("M200 S1 D1.75", r"m503.txt:18: M200 S1 \(volumetric extrusion on\)"),
])
def test_unmodelled_settings_are_named_warnings(tmp_path, line, match):
    text = REFERENCE_M503.replace("echo:  M206 X0.00 Y0.00 Z0.00", "echo:  " + line)
    assert text.splitlines()[17] == "echo:  " + line
    with pytest.warns(UserWarning, match=match):
        gp.load_machine(str(_report(tmp_path, text)))


def test_disabled_shaping_and_levelling_are_quiet(tmp_path):
    text = REFERENCE_M503.replace("echo:  M206 X0.00 Y0.00 Z0.00",
                                  "echo:  M593 X F0.00 D0.10\necho:  M420 S0 Z10.00\necho:  M200 S0 D2.85\n"
                                  "echo:  G29 W I0 J0 Z0.012")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gp.load_machine(str(_report(tmp_path, text)))


@pytest.mark.parametrize("line,match", [
    ("M92 X-100.00", r"m503.txt:18: M92 X \(steps/mm\) must be > 0"),
    ("M203 X0", r"m503.txt:18: M203 X \(max feedrate mm/s\) must be > 0"),
    ("M204 P0", r"m503.txt:18: M204 P must be > 0"),
    ("M205 Q1", r"m503.txt:18: M205 Q: not a Marlin M205 setting"),
    ("M205 J0.02", r"m503.txt:18: M205 gives both J .* and X/Y/Z jerks"),
    ("M900 K-1", r"m503.txt:18: M900 K must be >= 0"),
    ("G20", r"m503.txt:18: G20: the report is in inches"),
    ("M665 L250", r"m503.txt:18: M665: a delta"),
    ("M92 Xinf", r"m503.txt:18: M92 X must be a finite number"),
    ("M92 X1OO", r"m503.txt:18: M92 X: needs a number, got '1OO'"),
    ("this is not marlin", r"m503.txt:18: not an M503 report line"),
])
def test_bad_reports_name_the_file_and_line(tmp_path, line, match):
    # a line of the firmware's own (echo:) is a command; other text is not part of a report
    text = REFERENCE_M503.replace("echo:  M206 X0.00 Y0.00 Z0.00", line if line[0].islower() else "echo:  " + line)
    p = _report(tmp_path, text)
    from gcodeplan.config.marlin_report import load_marlin_report

    with pytest.raises(ConfigError, match=match):
        load_marlin_report(str(p))
    if "not marlin" not in line and line != "G20":
        with pytest.raises(ConfigError, match=match):
            gp.load_machine(str(p))         # recognised by content, then refused


def test_a_program_with_a_limits_header_is_not_a_report(tmp_path):
    """PrusaSlicer writes M201/M203/M204/M205 at the top of its G-code: a program is not a machine."""
    from gcodeplan.config.marlin_report import is_marlin_report

    prog = _report(tmp_path, "M201 X1000 Y1000\nM203 X200 Y200\nM204 P1250\nG28\nG1 X10 F600\n", "p.gcode")
    assert not is_marlin_report(str(prog))
    assert is_marlin_report(str(_report(tmp_path, REFERENCE_M503)))
    toml = _report(tmp_path, 'base = "marlin"\n', "m.toml")
    assert not is_marlin_report(str(toml))
    assert gp.load_machine(str(toml)).firmware == "marlin-2.1.2"


def test_the_marlin_preset_is_the_marlin_2_1_2_model():
    """Issue 21: `--machine marlin` is the Marlin 2.1.2 model with the reference's machine values, arcs in
    ARC_SUPPORT's 1 mm segments included: the same machine as the `marlin-2.1.2` preset."""
    _same_machine(gp.load_machine("marlin"), gp.load_machine("marlin-2.1.2"))
    assert gp.load_machine("marlin").arc_resolution == 1.0


def test_absurd_values_meet_the_machine_checks(tmp_path):
    p = _report(tmp_path, "M92 X100 Y100 Z400 E280\nM203 X1e-9 Y200\n")
    with pytest.raises(ConfigError, match=r"m503.txt: axis.x.max_velocity: must be at least 0.001 mm/s"):
        gp.load_machine(str(p))
