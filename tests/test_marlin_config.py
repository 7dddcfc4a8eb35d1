"""Marlin's Configuration.h / Configuration_adv.h as a machine (config/marlin_config.py): the reference build's
configuration gives the marlin preset's machine and its time (1130.895265 s on the cube, the firmware's own),
``#define``/``//#define``, ``#if`` blocks, brace arrays, the pair of files, and named warnings for what the model
does not run. The fixtures are small files in the shapes of Marlin 2.1.2's shipped configuration."""
import json
import warnings

import pytest

import gcodeplan as gp
from gcodeplan.errors import ConfigError
from gcodeplan.gcode.arcs_marlin import MarlinArcSettings
from conftest import SAMPLES, shared_path

CUBE = "prusaslicer25_cube20_marlin2"

# the reference build (shared/reference/marlin/README.md, "Machine"), in Configuration.h's own shapes
MAIN = """/**
 * Configuration.h (test fixture)
 */
#pragma once
#define CONFIGURATION_H_VERSION 02010204
#define MOTHERBOARD BOARD_RAMPS_14_EFB
#define X_BED_SIZE 250
#define Y_BED_SIZE 210
#define X_MIN_POS 0
#define Y_MIN_POS -4
#define Z_MIN_POS 0
#define X_MAX_POS X_BED_SIZE + 5
#define Y_MAX_POS (Y_BED_SIZE + 2.5)
#define Z_MAX_POS 210
#define MIN_SOFTWARE_ENDSTOPS
#define MAX_SOFTWARE_ENDSTOPS
//#define DISTINCT_E_FACTORS
#define DEFAULT_AXIS_STEPS_PER_UNIT   { 100, 100, 400, 280 }
#define DEFAULT_MAX_FEEDRATE          { 200, 200, 12, 120 }
//#define LIMITED_MAX_FR_EDITING
#define DEFAULT_MAX_ACCELERATION      { 1000, 1000, 200, 5000 }
#define DEFAULT_ACCELERATION          1250    // X, Y, Z and E acceleration for printing moves
#define DEFAULT_RETRACT_ACCELERATION  1250    // E acceleration for retracts
#define DEFAULT_TRAVEL_ACCELERATION   1500    // X, Y, Z acceleration for travel (non printing) moves
#define CLASSIC_JERK
#if ENABLED(CLASSIC_JERK)
  #define DEFAULT_XJERK  8.0
  #define DEFAULT_YJERK  8.0
  #define DEFAULT_ZJERK  0.4
  //#define LIMITED_JERK_EDITING
#endif
#define DEFAULT_EJERK    4.5  // May be used by Linear Advance
#if DISABLED(CLASSIC_JERK)
  #define JUNCTION_DEVIATION_MM 0.013 // (mm) Distance from real junction edge
  #define JD_HANDLE_SMALL_SEGMENTS
#endif
//#define S_CURVE_ACCELERATION
"""

ADV = """#pragma once
#define CONFIGURATION_ADV_H_VERSION 02010204
#define DEFAULT_MINIMUMFEEDRATE       0.0     // (mm/s) Minimum feedrate. Set with M205 S.
#define DEFAULT_MINTRAVELFEEDRATE     0.0
#define DEFAULT_MINSEGMENTTIME        20000   // (µs) Set with M205 B.
#define SLOWDOWN
#if ENABLED(SLOWDOWN)
  #define SLOWDOWN_DIVISOR 2
#endif
#define MINIMUM_PLANNER_SPEED 0.05 // (mm/s)
//#define LIN_ADVANCE
#if ENABLED(LIN_ADVANCE)
  #define ADVANCE_K 0.22
#endif
#define MIN_STEPS_PER_SEGMENT 6
#if ALL(HAS_MEDIA, DIRECT_STEPPING)
  #define BLOCK_BUFFER_SIZE  8
#elif HAS_MEDIA
  #define BLOCK_BUFFER_SIZE 16
#else
  #define BLOCK_BUFFER_SIZE 16
#endif
#define ARC_SUPPORT                   // Requires ~3226 bytes
#if ENABLED(ARC_SUPPORT)
  #define MIN_ARC_SEGMENT_MM      0.1 // (mm) Minimum length of each arc segment
  #define MAX_ARC_SEGMENT_MM      1.0 // (mm) Maximum length of each arc segment
  #define MIN_CIRCLE_SEGMENTS    72
  //#define ARC_SEGMENTS_PER_SEC 50
  #define N_ARC_CORRECTION       25
  //#define ARC_P_CIRCLES
#endif
//#define INPUT_SHAPING_X
//#define FT_MOTION
"""


def _pair(tmp_path, main=MAIN, adv=ADV, folder="cfg"):
    d = tmp_path / folder
    d.mkdir(exist_ok=True)
    (d / "Configuration.h").write_text(main)
    if adv is not None:
        (d / "Configuration_adv.h").write_text(adv)
    return d / "Configuration.h"


def _load(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        m = gp.load_machine(str(path))
    return m, [str(x.message) for x in w]


def test_the_reference_builds_configuration_is_the_marlin_preset(tmp_path):
    m, w = _load(_pair(tmp_path))
    assert w == []                              # nothing in the reference's configuration is unmodelled
    preset = gp.load_machine("marlin")
    assert m.firmware == "marlin-2.1.2" and m.junction_policy == "classic-jerk"
    assert m.marlin_arcs == MarlinArcSettings()
    for a in "xyze":
        assert m.axes[a] == preset.axes[a], a    # steps, rates, accels, jerks, travel (X_BED_SIZE + 5 = 255)
    for k in ("max_accel", "accel_print", "accel_retract", "accel_travel", "max_velocity", "arc_resolution",
              "pressure_advance", "acceleration_profile", "kinematics", "flavor"):
        assert getattr(m, k) == getattr(preset, k), k


def test_the_reference_builds_configuration_runs_the_cube_as_marlin(tmp_path, capsys):
    est = gp.estimate(str(SAMPLES / (CUBE + ".gcode")), gp.load_machine(str(_pair(tmp_path))))
    assert est.time.total_time_s == pytest.approx(1130.89526516, abs=1e-8)
    times = json.loads(shared_path("reference", "marlin", "times.json").read_text())
    assert est.time.total_time_s == pytest.approx(times[CUBE + ".gcode"]["total_time_s"], abs=1e-6)


def test_the_adv_file_finds_its_configuration_h(tmp_path):
    p = _pair(tmp_path)
    m, _ = _load(p.parent / "Configuration_adv.h")
    assert m.axes["x"].steps_per_mm == 100 and m.junction_policy == "classic-jerk"
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "Configuration_adv.h").write_text(ADV)
    with pytest.raises(ConfigError, match="Configuration_adv.h alone"):
        gp.load_machine(str(alone / "Configuration_adv.h"))


def test_without_the_adv_file_marlins_defaults_and_a_warning(tmp_path):
    m, w = _load(_pair(tmp_path, adv=None))
    assert m.marlin_arcs == MarlinArcSettings() and m.pressure_advance == 0
    assert len(w) == 1 and "no Configuration_adv.h" in w[0]


def test_commented_defines_are_off_and_if_blocks_follow_them(tmp_path):
    main = MAIN.replace("#define CLASSIC_JERK", "//#define CLASSIC_JERK") \
        .replace("JUNCTION_DEVIATION_MM 0.013", "JUNCTION_DEVIATION_MM 0.02") \
        .replace("//#define S_CURVE_ACCELERATION", "#define S_CURVE_ACCELERATION")
    adv = ADV.replace("//#define LIN_ADVANCE", "#define LIN_ADVANCE").replace("ADVANCE_K 0.22", "ADVANCE_K 0.05")
    m, w = _load(_pair(tmp_path, main, adv))
    assert (m.junction_policy, m.junction_deviation) == ("junction-deviation", 0.02)
    assert [m.axes[a].jerk for a in "xyz"] == [8.0, 8.0, 0.4]      # the preset's: DEFAULT_XJERK is inside #if off
    assert m.acceleration_profile == "s-curve" and m.pressure_advance == 0.05
    assert w == []


def test_the_jd_variant_configuration_gives_its_total(tmp_path):
    """shared/reference/marlin/variants/jd: CLASSIC_JERK off, JUNCTION_DEVIATION_MM 0.013."""
    times = json.loads(shared_path("reference", "marlin", "variants", "jd", "times.json").read_text())
    m, _ = _load(_pair(tmp_path, MAIN.replace("#define CLASSIC_JERK", "//#define CLASSIC_JERK")))
    est = gp.estimate(str(shared_path("gcode", CUBE + ".gcode")), m)
    assert est.time.total_time_s == pytest.approx(times[CUBE + ".gcode"]["total_time_s"], abs=1e-6)


def test_arrays_expressions_and_extruder_lists(tmp_path):
    main = MAIN.replace("{ 100, 100, 400, 280 }", "{ 80, 80, 200*16/8, 415.0f, 93 }") \
        .replace("//#define DISTINCT_E_FACTORS", "#define DISTINCT_E_FACTORS")
    m, w = _load(_pair(tmp_path, main))
    assert [m.axes[a].steps_per_mm for a in "xyze"] == [80, 80, 400, 415]
    assert len(w) == 1 and "Configuration.h:18: DEFAULT_AXIS_STEPS_PER_UNIT: values for 2 extruders" in w[0]


def test_arc_settings_are_read(tmp_path):
    adv = ADV.replace("MAX_ARC_SEGMENT_MM      1.0", "MAX_ARC_SEGMENT_MM      2.0") \
        .replace("//#define ARC_SEGMENTS_PER_SEC 50", "#define ARC_SEGMENTS_PER_SEC 40") \
        .replace("N_ARC_CORRECTION       25", "N_ARC_CORRECTION       12") \
        .replace("//#define ARC_P_CIRCLES", "#define ARC_P_CIRCLES")
    m, _ = _load(_pair(tmp_path, adv=adv))
    assert m.marlin_arcs == MarlinArcSettings(0.1, 2.0, 72, 40.0, 12, p_circles=True)
    assert m.arc_resolution == 2.0


def test_arc_support_off_refuses_arcs_naming_the_line(tmp_path):
    m, w = _load(_pair(tmp_path, adv=ADV.replace("#define ARC_SUPPORT ", "//#define ARC_SUPPORT ")))
    assert any("ARC_SUPPORT off" in x for x in w)
    g = tmp_path / "a.gcode"
    g.write_text("G1 X10 Y10 F3000\nG2 X20 Y20 I10 J0\n")
    with pytest.raises(gp.GcodeplanError) as err:
        gp.estimate(str(g), m)
    assert err.value.line == 2 and "ARC_SUPPORT off" in str(err.value)


@pytest.mark.parametrize("edit, where, name", [
    (("//#define INPUT_SHAPING_X", "#define INPUT_SHAPING_X"), "Configuration_adv.h:32", "INPUT_SHAPING_X"),
    (("//#define FT_MOTION", "#define FT_MOTION"), "Configuration_adv.h:33", "FT_MOTION"),
    (("//#define FT_MOTION", "#define ADAPTIVE_STEP_SMOOTHING"), "Configuration_adv.h:33", "ADAPTIVE_STEP_SMOOTHING"),
    (("MINIMUM_PLANNER_SPEED 0.05", "MINIMUM_PLANNER_SPEED 0.5"), "Configuration_adv.h:10", "MINIMUM_PLANNER_SPEED"),
    (("MIN_STEPS_PER_SEGMENT 6", "MIN_STEPS_PER_SEGMENT 1"), "Configuration_adv.h:15", "MIN_STEPS_PER_SEGMENT"),
    (("DEFAULT_MINSEGMENTTIME        20000", "DEFAULT_MINSEGMENTTIME 50000"), "Configuration_adv.h:5",
     "DEFAULT_MINSEGMENTTIME"),
    (("#define SLOWDOWN\n", "//#define SLOWDOWN\n"), "Configuration_adv.h:6", "SLOWDOWN off"),
    (("#elif HAS_MEDIA\n  #define BLOCK_BUFFER_SIZE 16", "#elif HAS_MEDIA\n  #define BLOCK_BUFFER_SIZE 64"),
     "Configuration_adv.h:19",
     "BLOCK_BUFFER_SIZE"),
    (("DEFAULT_MINIMUMFEEDRATE       0.0", "DEFAULT_MINIMUMFEEDRATE 5"), "Configuration_adv.h:3", "M205 S5"),
])
def test_unmodelled_timing_settings_are_named_warnings(tmp_path, edit, where, name):
    assert edit[0] in ADV
    m, w = _load(_pair(tmp_path, adv=ADV.replace(*edit)))
    assert any(where in x and name in x for x in w), w


def test_unevaluated_conditions_are_named(tmp_path):
    main = MAIN.replace("#define DEFAULT_ACCELERATION          1250",
                        "#if X_DRIVER_TYPE == TMC2209\n#define DEFAULT_ACCELERATION 900\n#endif")
    m, w = _load(_pair(tmp_path, main))
    assert m.accel_print == 900
    assert any("DEFAULT_ACCELERATION is defined under '#if X_DRIVER_TYPE == TMC2209'" in x for x in w), w


@pytest.mark.parametrize("edit, match, line", [
    (("{ 1000, 1000, 200, 5000 }", "{ 0, 1000, 200, 5000 }"), r"DEFAULT_MAX_ACCELERATION .* X must be > 0", 21),
    (("{ 200, 200, 12, 120 }", "{ 200, 200 }"), "needs X, Y, Z and E values", 19),
    (("DEFAULT_ACCELERATION          1250", "DEFAULT_ACCELERATION nope"), "not a number", 22),
    (("DEFAULT_ACCELERATION          1250", "DEFAULT_ACCELERATION -5"), "must be > 0", 22),
    (("//#define DISTINCT_E_FACTORS", "#define DELTA"), "cartesian, COREXY and COREXZ machines only", 17),
    (("//#define DISTINCT_E_FACTORS", "#define COREYX"), "cartesian, COREXY and COREXZ machines only", 17),
    (("#define CLASSIC_JERK", "#define CLASSIC_JERK\n#if 0"), "#if without #endif", None),
    (("//#define S_CURVE_ACCELERATION", "#error \"bad board\""), "#error", 37),
])
def test_bad_configurations_name_file_and_line(tmp_path, edit, match, line):
    assert edit[0] in MAIN
    with pytest.raises(ConfigError, match=match) as err:
        gp.load_machine(str(_pair(tmp_path, MAIN.replace(*edit))))
    assert err.value.line == line
    assert "Configuration.h" in str(err.value)


@pytest.mark.parametrize("define, kinematics", [("COREXY", "corexy"), ("COREXZ", "corexz")])
def test_a_core_build_is_read_as_its_kinematics(tmp_path, define, kinematics):
    # Marlin's COREXY / COREXZ builds run on the Marlin model (tests/test_marlin_core.py): the machine says so
    assert "//#define DISTINCT_E_FACTORS" in MAIN
    m, _ = _load(_pair(tmp_path, MAIN.replace("//#define DISTINCT_E_FACTORS", f"#define {define}")))
    assert m.kinematics == kinematics and m.firmware == "marlin-2.1.2"
    m0, _ = _load(_pair(tmp_path, folder="plain"))
    assert m0.kinematics == "cartesian"


def test_cli_prints_config_warnings_as_one_line(tmp_path, capsys):
    from gcodeplan.cli import main

    p = _pair(tmp_path, adv=ADV.replace("//#define FT_MOTION", "#define FT_MOTION"))
    g = tmp_path / "a.gcode"
    g.write_text("G1 X10 Y10 F3000\n")
    assert main(["estimate", "--machine", str(p), str(g)]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("gcodeplan: warning: ") and "FT_MOTION on" in lines[0]
    assert "UserWarning" not in err
