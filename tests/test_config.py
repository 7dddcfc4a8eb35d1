"""Machine configuration: TOML loader, Klipper printer.cfg reader, presets, validation.

Truth used here: values worked out by hand from the formulas (Klipper's stepper and extruder rules),
Klipper's own reference config (shared/reference/klipper), and the machine-limit header PrusaSlicer wrote
into the shared corpus files (for the marlin preset).
"""
from __future__ import annotations

import argparse
import math
import os
import re
from dataclasses import fields, replace
from pathlib import Path

import pytest

from conftest import shared_path
from gcodeplan.config import (
    load_klipper_config,
    load_machine,
    machine_from_args,
    machine_to_toml,
    parse_gear_ratio,
    preset_names,
    steps_per_mm_from_rotation,
    validate,
)
from gcodeplan.errors import ConfigError
from gcodeplan.machine import AXES, Axis, Machine

DATA = Path(__file__).parent / "data" / "config"
FILAMENT_AREA_175 = math.pi * 0.875 ** 2          # mm², 1.75 mm filament


def write(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def assert_same_machine(a: Machine, b: Machine, skip: tuple[str, ...] = ("name",)) -> None:
    """Field by field, so a failure names the field (axes: per axis and attribute)."""
    for f in fields(Machine):
        if f.name in skip or not f.compare:      # auto_flavor: how the machine was chosen, not what it is
            continue
        if f.name == "axes":
            for ax in AXES:
                for g in fields(Axis):
                    assert getattr(a.axes[ax], g.name) == getattr(b.axes[ax], g.name), f"axes[{ax}].{g.name}"
        else:
            assert getattr(a, f.name) == getattr(b, f.name), f.name


# ============================================================================ pure formulas

def test_steps_per_mm_by_hand():
    # 200 full steps × 16 microsteps per 40 mm belt rotation = 3200/40
    assert steps_per_mm_from_rotation(40.0, 16, 200) == 80.0
    # 3:1 reduction: three motor turns per output turn
    assert steps_per_mm_from_rotation(40.0, 16, 200, 3.0) == 240.0
    assert steps_per_mm_from_rotation(8.0, 16, 200) == 400.0


def test_gear_ratio_product():
    assert parse_gear_ratio("3:1") == 3.0
    assert parse_gear_ratio("57:11, 3:1") == pytest.approx(57 / 11 * 3, rel=1e-15)
    assert parse_gear_ratio("50:10,\n2:4") == 2.5
    for bad in ("3", "3:0", "a:1", "", "3:1:2", "-3:1"):
        with pytest.raises(ValueError):
            parse_gear_ratio(bad)


# ============================================================================ presets

def test_preset_names():
    assert preset_names() == ["grbl", "klipper", "linuxcnc", "marlin", "marlin-2.1.2", "marlin-bugfix"]


def test_klipper_preset_equals_klipper_reference_cfg():
    cfg = load_klipper_config(str(shared_path("reference", "klipper", "cartesian_corpus.cfg")))
    assert_same_machine(load_machine("klipper"), cfg)


def test_corexy_reference_cfg_differs_from_preset_only_in_kinematics():
    cfg = load_klipper_config(str(shared_path("reference", "klipper", "corexy_corpus.cfg")))
    assert cfg.kinematics == "corexy"
    assert_same_machine(replace(load_machine("klipper"), kinematics="corexy"), cfg)


def test_klipper_preset_values_by_hand():
    m = load_machine("klipper")
    assert (m.flavor, m.junction_policy, m.kinematics) == ("klipper", "klipper", "cartesian")
    assert (m.max_velocity, m.max_accel, m.square_corner_velocity, m.minimum_cruise_ratio) == (300, 3000, 5, 0.5)
    assert (m.axes["z"].max_velocity, m.axes["z"].max_accel) == (15, 100)
    assert m.axes["x"].max_velocity == m.axes["y"].max_accel == math.inf    # Klipper has no X/Y limits
    assert [m.axes[a].steps_per_mm for a in "xyz"] == [80, 80, 400]
    assert m.axes["e"].steps_per_mm == pytest.approx(200 * 16 / 33.5, rel=1e-15)
    ratio0 = 4 * 0.4 ** 2 / FILAMENT_AREA_175                              # 0.26608...
    assert ratio0 == pytest.approx(0.26608, abs=1e-5)
    assert m.max_extrude_only_velocity == pytest.approx(300 * ratio0, rel=1e-15)
    assert m.max_extrude_only_accel == pytest.approx(3000 * ratio0, rel=1e-15)
    assert m.max_extrude_only_velocity == pytest.approx(79.82, abs=0.005)
    assert m.max_extrude_ratio == pytest.approx(50 / FILAMENT_AREA_175, rel=1e-15)
    assert (m.instantaneous_corner_velocity, m.arc_resolution) == (1.0, 1.0)


def test_marlin_preset_matches_prusaslicer_header():
    """The PrusaSlicer corpus files carry the MK3S limits as M201/M203/M204/M205: compare to them."""
    gcode = shared_path("gcode", "prusaslicer25_cube20_marlin2.gcode")
    header = {}
    with open(gcode) as fh:
        for _, line in zip(range(400), fh):
            code = line.split(";")[0].split()
            if code and code[0] in ("M201", "M203", "M204", "M205") and code[0] not in header:
                header[code[0]] = {w[0]: float(w[1:]) for w in code[1:]}
    m = load_machine("marlin")
    for a in "xyz":
        assert m.axes[a].max_accel == header["M201"][a.upper()]
        assert m.axes[a].max_velocity == header["M203"][a.upper()]
        assert m.axes[a].jerk == header["M205"][a.upper()]
    assert m.axes["e"].max_accel == header["M201"]["E"]
    assert m.axes["e"].max_velocity == header["M203"]["E"]
    assert m.axes["e"].jerk == header["M205"]["E"]
    assert (m.accel_print, m.accel_retract, m.accel_travel) == (
        header["M204"]["P"], header["M204"]["R"], header["M204"]["T"])
    assert (m.flavor, m.junction_policy) == ("marlin", "classic-jerk")
    assert [m.axes[a].steps_per_mm for a in AXES] == [100, 100, 400, 280]


def test_grbl_preset_values():
    m = load_machine("grbl")
    assert (m.flavor, m.junction_policy, m.junction_deviation, m.arc_tolerance) == (
        "grbl", "junction-deviation", 0.01, 0.002)
    assert m.axes["x"].max_velocity == pytest.approx(5000 / 60, rel=1e-15)     # $110 mm/min → mm/s
    assert m.axes["z"].max_velocity == pytest.approx(1000 / 60, rel=1e-15)
    assert (m.axes["x"].max_accel, m.axes["y"].max_accel, m.axes["z"].max_accel) == (500, 500, 200)
    assert all(m.axes[a].steps_per_mm == 250 for a in "xyz")
    assert m.is_cnc


# ============================================================================ TOML

def test_empty_toml_is_machine_defaults(tmp_path):
    assert_same_machine(load_machine(write(tmp_path, "m.toml", "")), Machine(), skip=())


def test_partial_toml_keeps_defaults():
    m = load_machine(str(DATA / "partial.toml"))
    d = Machine()
    assert (m.name, m.flavor, m.max_accel, m.accel_travel) == ("partial", "reprap", 1500, math.inf)
    assert m.axes["x"].steps_per_mm == 240.0            # 200·16·3/40
    assert m.axes["z"].max_velocity == math.inf and m.axes["z"].steps_per_mm == 400
    assert_same_machine(replace(m, name=d.name, flavor=d.flavor, max_accel=d.max_accel, accel_travel=None,
                                axes=d.axes), d, skip=())


def test_toml_base_preset_then_override():
    m = load_machine(str(DATA / "based_on_marlin.toml"))
    marlin = load_machine("marlin")
    assert (m.name, m.axes["x"].max_accel, m.arc_tolerance) == ("my-mk3s", 2000, 0.01)
    marlin.axes["x"].max_accel = 2000
    assert_same_machine(replace(m, arc_tolerance=marlin.arc_tolerance), marlin)


def test_toml_base_file_and_self_reference(tmp_path):
    write(tmp_path, "shop.toml", "base = \"grbl\"\n[axis.z]\nsteps_per_mm = 1000\n")
    m = load_machine(write(tmp_path, "mill.toml", "base = \"shop.toml\"\nname = \"mill\"\n"))
    assert (m.name, m.flavor, m.axes["z"].steps_per_mm, m.axes["x"].steps_per_mm) == ("mill", "grbl", 1000, 250)
    loop = write(tmp_path, "loop.toml", "base = \"loop.toml\"\n")
    with pytest.raises(ConfigError, match=r"loop\.toml: base: 'loop\.toml' includes itself"):
        load_machine(loop)
    bad_base = write(tmp_path, "badbase.toml", "[toolhead]\nmax_accel = 0\n")
    with pytest.raises(ConfigError, match=r"badbase\.toml: toolhead\.max_accel"):     # names the base's file
        load_machine(write(tmp_path, "child.toml", "base = \"badbase.toml\"\n"))


@pytest.mark.parametrize("preset", ["klipper", "marlin", "grbl"])
def test_round_trip_presets(tmp_path, preset):
    m = load_machine(preset)
    assert_same_machine(load_machine(write(tmp_path, "m.toml", machine_to_toml(m))), m, skip=())


def test_round_trip_every_field_changed(tmp_path):
    m = Machine(name='odd "name"', kinematics="corexy", flavor="linuxcnc", max_velocity=123.456,
                max_accel=1e4, accel_print=1000.0, accel_travel=2000.5, accel_retract=math.inf,
                rapid_velocity=400.0, junction_policy="blend", square_corner_velocity=0.0,
                minimum_cruise_ratio=0.0, junction_deviation=0.05, blend_tolerance=0.1, max_jerk=5e4,
                nozzle_diameter=0.25, filament_diameter=2.85, max_extrude_only_velocity=50.0,
                max_extrude_only_accel=500.0, instantaneous_corner_velocity=0.0, max_extrude_ratio=3.0,
                arc_tolerance=0.01, arc_resolution=0.25, retract_length=1.5, retract_speed=40.0,
                unretract_extra_length=0.1, unretract_speed=30.0, homing_time=12.0, heat_wait_time=60.0,
                max_step_rate=2e5)
    m.axes["x"] = Axis(1 / 3, 0.1, 7.5, 1 / 0.0125, -3.25)
    m.axes["e"] = Axis(max_velocity=25.0, jerk=math.inf, steps_per_mm=415.0)
    assert_same_machine(load_machine(write(tmp_path, "m.toml", machine_to_toml(m))), m, skip=())


def test_inf_spellings(tmp_path):
    text = ("[toolhead]\nmax_velocity = inf\nmax_accel = \"inf\"\n[axis.z]\nmax_velocity = +inf\n"
            "[junction]\npolicy = \"junction-deviation\"\n")
    m = load_machine(write(tmp_path, "m.toml", text))
    assert m.max_velocity == m.max_accel == m.axes["z"].max_velocity == math.inf


TOML_ERRORS = [
    ("[toolhead]\nmax_accel = -5\n", "m.toml: toolhead.max_accel: must be at least 0.001 mm/s² (inf = no limit), got -5"),
    ("[toolhead]\nmax_velocity = 0\n", "toolhead.max_velocity: must be at least 0.001 mm/s (inf = no limit), got 0"),
    ("[toolhead]\nmax_accel = nan\n", "toolhead.max_accel: must be at least 0.001 mm/s² (inf = no limit), got nan"),
    ("[toolhead]\nmax_accel = \"fast\"\n", "toolhead.max_accel: must be a number, got 'fast'"),
    ("[toolhead]\nmax_accel = true\n", "toolhead.max_accel: must be a number, got true"),
    ("[toolhead]\naccel_print = -1.5\n", "toolhead.accel_print: must be at least 0.001 mm/s² (inf = no limit), got -1.5"),
    ("[toolhead]\nmax_acel = 5\n", "toolhead.max_acel: unknown key (did you mean 'max_accel'?)"),
    ("[tolhead]\nmax_accel = 5\n", "tolhead: unknown section (did you mean 'toolhead'?)"),
    ("[junction]\nminimum_cruise_ratio = 1.0\n", "junction.minimum_cruise_ratio: must be a number in [0, 1), got 1"),
    ("[junction]\nminimum_cruise_ratio = -0.1\n", "junction.minimum_cruise_ratio: must be a number in [0, 1), got -0.1"),
    ("[junction]\npolicy = \"jerk\"\n", "junction.policy: unknown value 'jerk': must be one of klipper, "),
    ("[junction]\njunction_deviation = inf\n", "junction.junction_deviation: must be a finite number >= 0, got inf"),
    ("[junction]\nsquare_corner_velocity = -1\n", "junction.square_corner_velocity: must be a finite number >= 0"),
    ("kinematics = \"delta\"\n", "delta.radius: kinematics 'delta' needs delta_radius > 0 mm, got 0.0"),
    ("kinematics = \"delta\"\n[delta]\nradius = 100\narm_length = [250, 90, 250]\n",
     "delta.arm_length: tower b's arm (90 mm) must be longer than delta_radius (100 mm)"),
    ("[delta]\nangle = [1, 2]\n", "delta.angle: must be a number or an array of three numbers (towers a, b, c), "
                                  "got an array"),
    ("kinematics = \"coreXY\"\n", "kinematics: unknown value 'coreXY': must be one of cartesian, corexy, "
                                  "corexz, delta, polar, rotary_delta, winch, deltesian, hybrid_corexy, "
                                  "hybrid_corexz, generic_cartesian (did you mean 'corexy'?)"),
    ("kinematics = 3\n", "kinematics: must be a string, got 3"),
    ("flavor = \"marlinn\"\n", "flavor: unknown value 'marlinn'"),
    ("flavour = \"marlin\"\n", "flavour: unknown key (did you mean 'flavor'?)"),
    ("max_accel = 3000\n", "max_accel: unknown top-level key (it belongs in [toolhead])"),
    ("toolhead = 5\n", "toolhead: must be a table [toolhead], got 5"),
    ("[axis.w]\nmax_accel = 5\n", "axis.w: unknown axis (axes are x, y, z, e)"),
    ("[axis.x]\nsteps_per_mm = 0\n", "axis.x.steps_per_mm: must be a number of steps/mm from 0.001 (a step of 1 m) to 1e6 (a step of 1 nm), got 0"),
    ("[axis.x]\nsteps = 80\n", "axis.x.steps: unknown key (did you mean 'steps_per_mm'?)"),
    ("[axis.x]\nhome = inf\n", "axis.x.home: must be a finite number, got inf"),
    ("[axis.y]\nsteps_per_mm = 80\nrotation_distance = 40\nmicrosteps = 16\n",
     "axis.y.steps_per_mm: give steps_per_mm or rotation_distance (+ microsteps), not both"),
    ("[axis.y]\nrotation_distance = 40\n", "axis.y.microsteps: required with rotation_distance"),
    ("[axis.y]\nmicrosteps = 16\n", "axis.y.microsteps: needs axis.y.rotation_distance"),
    ("[axis.y]\nrotation_distance = 40\nmicrosteps = 16.5\n", "axis.y.microsteps: must be a positive integer, got 16.5"),
    ("[axis.y]\nrotation_distance = -40\nmicrosteps = 16\n", "axis.y.rotation_distance: must be a positive finite"),
    ("[axis.y]\nrotation_distance = 40\nmicrosteps = 16\ngear_ratio = \"3\"\n",
     "axis.y.gear_ratio: expected 'a:b' pairs separated by commas, got '3'"),
    ("[extruder]\nfilament_diameter = 0\n", "extruder.filament_diameter: must be a positive finite number, got 0"),
    ("[extruder]\nmax_extrude_ratio = 2\nmax_extrude_cross_section = 4\n",
     "extruder.max_extrude_cross_section: give it or max_extrude_ratio, not both"),
    ("[arcs]\ntolerance = 0\n", "arcs.tolerance: must be a positive finite number, got 0"),
    ("[firmware_retraction]\nretract_speed = 0\n", "firmware_retraction.retract_speed: must be a finite speed of at least 0.001 mm/s, got 0"),
    ("[time]\nhoming_time = -1\n", "time.homing_time: must be a finite number >= 0, got -1"),
    ("[stepper]\nmax_step_rate = -1\n", "stepper.max_step_rate: must be a positive number"),
    ("[toolhead]\nmax_accel = inf\n", "toolhead.max_accel: must be finite with junction.policy 'klipper', got inf"),
    ("base = \"prusa\"\n", "base: 'prusa' is neither a preset"),
]


@pytest.mark.parametrize("text,message", TOML_ERRORS,
                         ids=[f"{i}-" + m.removeprefix("m.toml: ").split(":")[0] for i, (_, m) in enumerate(TOML_ERRORS)])
def test_toml_errors_name_the_key(tmp_path, text, message):
    path = write(tmp_path, "m.toml", text)
    with pytest.raises(ConfigError) as err:
        load_machine(path)
    msg = str(err.value)
    assert msg.startswith(path + ": "), msg
    assert message.removeprefix("m.toml: ") in msg, msg


def test_toml_syntax_error_gives_line(tmp_path):
    path = write(tmp_path, "m.toml", "name = \"a\"\n\n[toolhead]\nmax_accel = = 3\n")
    with pytest.raises(ConfigError) as err:
        load_machine(path)
    assert err.value.line == 4 and err.value.file == path
    assert str(err.value).startswith(f"{path}:4: TOML syntax error: ")


def test_missing_and_unreadable_files(tmp_path):
    (tmp_path / "bin.toml").write_bytes(b"name = \"\xff\xfe\"\n")
    cases = {
        str(tmp_path / "nope.toml"): "no such file",
        str(tmp_path): "is a directory",
        str(tmp_path / "bin.toml"): "not a UTF-8 text file",
    }
    for path, fragment in cases.items():
        with pytest.raises(ConfigError, match=re.escape(fragment)):
            load_machine(path)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root reads any file")
def test_permission_denied(tmp_path):
    path = write(tmp_path, "m.toml", "")
    os.chmod(path, 0)
    with pytest.raises(ConfigError, match="permission denied"):
        load_machine(path)


def test_unknown_preset_and_cfg_hint(tmp_path):
    with pytest.raises(ConfigError, match=r"neither a file nor a preset; presets: grbl, klipper, linuxcnc, marlin, "
                                          r"marlin-2.1.2, marlin-bugfix "
                                          r"\(did you mean 'marlin'\?\)"):
        load_machine("marlen")
    cfg = write(tmp_path, "printer.cfg", "[printer]\n")
    with pytest.raises(ConfigError, match="kinematics is required"):     # read as a printer.cfg
        load_machine(cfg)


def test_directory_named_like_a_preset_does_not_shadow_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "klipper").mkdir()
    assert load_machine("klipper").flavor == "klipper"


# ============================================================================ validate()

@pytest.mark.parametrize("change,key", [
    (dict(max_accel=-1.0), "toolhead.max_accel"),
    (dict(minimum_cruise_ratio=1.0), "junction.minimum_cruise_ratio"),
    (dict(flavor="makerbot"), "flavor"),
    (dict(kinematics="delta"), "delta.radius"),
    (dict(arc_tolerance=float("nan")), "arcs.tolerance"),
    (dict(accel_travel=0.0), "toolhead.accel_travel"),
    (dict(max_velocity="300"), "toolhead.max_velocity"),
])
def test_validate_names_the_key(change, key):
    with pytest.raises(ConfigError, match="^" + re.escape(key) + ": "):
        validate(replace(Machine(), **change))


def test_validate_axes():
    validate(Machine())                                           # the defaults are valid
    m = Machine()
    m.axes["y"].steps_per_mm = 0.0
    with pytest.raises(ConfigError, match=r"^axis\.y\.steps_per_mm: must be a number of steps/mm from 0\.001 .*, got 0$"):
        validate(m)
    m = Machine()
    del m.axes["e"]
    with pytest.raises(ConfigError, match="axis: the axes must be exactly x, y, z, e"):
        validate(m)


# ============================================================================ Klipper printer.cfg

def test_klipper_reference_cfg_by_hand():
    m = load_klipper_config(str(shared_path("reference", "klipper", "cartesian_corpus.cfg")))
    assert (m.flavor, m.junction_policy, m.kinematics, m.name) == ("klipper", "klipper", "cartesian",
                                                                   "cartesian_corpus")
    assert [m.axes[a].steps_per_mm for a in "xyz"] == [80.0, 80.0, 400.0]    # 3200/40, 3200/40, 3200/8
    assert m.axes["e"].steps_per_mm == 3200 / 33.5
    assert (m.axes["z"].max_velocity, m.axes["z"].max_accel) == (15.0, 100.0)
    assert m.max_extrude_only_accel == pytest.approx(798.2, abs=0.05)


def test_klipper_include_glob_save_config_comments():
    m = load_klipper_config(str(DATA / "include_main.cfg"))
    assert m.kinematics == "corexy"
    assert m.max_velocity == 250.0                     # '=' separator, ';' comment
    assert m.max_accel == 2000.0                       # Klipper drops a saved key the config sets (configfile.py)
    assert m.square_corner_velocity == 8.0
    assert (m.axes["z"].max_velocity, m.axes["z"].max_accel) == (10.0, 50.0)
    assert m.axes["x"].steps_per_mm == 80.0 and m.axes["x"].home == -5.0
    assert m.axes["y"].steps_per_mm == 400 * 32 * 3 / 40 == 960.0
    assert m.axes["y"].home == 210.0
    # continuation line: gear_ratio 3:1 · 2:4 = 1.5 → 3200·1.5/8
    assert m.axes["z"].steps_per_mm == 600.0
    assert m.axes["z"].home == 0.5                     # the included 0.5 wins over the saved 0.735, as in Klipper
    assert m.axes["e"].steps_per_mm == pytest.approx(3200 * 5 / 22.6789511, rel=1e-15)
    ratio0 = 4 * 0.6 ** 2 / FILAMENT_AREA_175
    assert m.max_extrude_only_velocity == 120.0
    assert m.max_extrude_only_accel == pytest.approx(2000 * ratio0, rel=1e-15)   # uses the final max_accel
    assert m.max_extrude_ratio == pytest.approx(ratio0, rel=1e-15)               # default cross-section 4·nozzle²
    assert (m.retract_length, m.retract_speed, m.unretract_extra_length, m.unretract_speed) == (0.8, 35, 0, 10)
    assert m.arc_resolution == 0.5


def test_klipper_max_accel_to_decel_and_defaults():
    m = load_klipper_config(str(DATA / "max_accel_to_decel.cfg"))
    assert m.minimum_cruise_ratio == 1 - 1000 / 4000
    assert m.square_corner_velocity == 5.0
    assert (m.axes["z"].max_velocity, m.axes["z"].max_accel) == (200.0, 4000.0)   # default to the toolhead's
    assert m.axes["x"].steps_per_mm == 100.0
    assert m.arc_resolution == 0.0                     # no [gcode_arcs]: chord tolerance
    d = Machine()
    assert (m.max_extrude_only_velocity, m.axes["e"].steps_per_mm) == (d.max_extrude_only_velocity,
                                                                      d.axes["e"].steps_per_mm)


MINIMAL = """\
[printer]
kinematics: cartesian
max_velocity: 300
max_accel: 3000
{printer}
[stepper_x]
rotation_distance: 40
microsteps: 16
{stepper_x}
[stepper_y]
rotation_distance: 40
microsteps: 16
[stepper_z]
rotation_distance: 8
microsteps: 16
"""


def minimal(printer: str = "", stepper_x: str = "") -> str:
    return MINIMAL.format(printer=printer, stepper_x=stepper_x)


@pytest.mark.parametrize("a2d,mcr_extra,expected", [
    ("1500", "", 0.5),
    ("3000", "", 0.0),
    ("9000", "", 0.0),                                 # clipped: never negative
    ("1000", "minimum_cruise_ratio: 0.25", 0.25),       # the newer key wins
])
def test_klipper_accel_to_decel_mapping(tmp_path, a2d, mcr_extra, expected):
    path = write(tmp_path, "printer.cfg", minimal(f"max_accel_to_decel: {a2d}\n{mcr_extra}"))
    assert load_klipper_config(path).minimum_cruise_ratio == pytest.approx(expected, abs=1e-15)


def test_klipper_extruder_without_stepper(tmp_path):
    path = write(tmp_path, "printer.cfg", minimal() + "[extruder]\nnozzle_diameter: 0.5\nfilament_diameter: 2.85\n")
    m = load_klipper_config(path)
    assert m.axes["e"].steps_per_mm == Machine().axes["e"].steps_per_mm
    ratio0 = 4 * 0.5 ** 2 / (math.pi * (2.85 / 2) ** 2)
    assert (m.max_extrude_only_velocity, m.max_extrude_only_accel) == (300 * ratio0, 3000 * ratio0)
    bad = write(tmp_path, "bad.cfg", minimal() + "[extruder]\nstep_pin: PA1\nnozzle_diameter: 0.5\n"
                                                  "filament_diameter: 2.85\n")
    with pytest.raises(ConfigError, match=r"\[extruder\] rotation_distance is required"):
        load_klipper_config(bad)


def test_klipper_gear_ratio_240(tmp_path):
    path = write(tmp_path, "printer.cfg", minimal(stepper_x="gear_ratio: 3:1"))
    assert load_klipper_config(path).axes["x"].steps_per_mm == 240.0


def test_klipper_bad_number_names_file_line_section_key(tmp_path):
    path = write(tmp_path, "printer.cfg", minimal().replace("max_accel: 3000", "max_accel: abc"))
    with pytest.raises(ConfigError) as err:
        load_klipper_config(path)
    assert str(err.value) == f"{path}:4: [printer] max_accel: not a number: 'abc'"


KLIPPER_ERRORS = [
    # (change applied to MINIMAL, expected message after "file[:line]: ")
    (lambda t: t.replace("max_velocity: 300\n", ""), "[printer] max_velocity is required"),
    (lambda t: t.replace("max_accel: 3000\n", ""), "[printer] max_accel is required"),
    (lambda t: t.replace("kinematics: cartesian", "kinematics: delta"),
     "[stepper_a] section is required (kinematics: delta)"),
    (lambda t: t.replace("kinematics: cartesian", "kinematics: scara"),
     "[printer] kinematics: kinematics 'scara' is not supported"),
    (lambda t: t.replace("kinematics: cartesian\n", ""), "[printer] kinematics is required"),
    (lambda t: t.replace("max_velocity: 300", "max_velocity: -300"),
     "[printer] max_velocity: must be above 0, got -300"),
    (lambda t: t.replace("max_velocity: 300", "max_velocity: nan"),
     "[printer] max_velocity: must be a finite number, got 'nan'"),
    (lambda t: t.replace("max_velocity: 300", "max_velocity: 300\nmax_z_velocity: 301"),
     "[printer] max_z_velocity: must be at most 300, got 301"),
    (lambda t: t.replace("max_velocity: 300", "max_velocity: 300\nminimum_cruise_ratio: 1"),
     "[printer] minimum_cruise_ratio: must be below 1, got 1"),
    (lambda t: t.replace("[stepper_y]\nrotation_distance: 40\n", "[stepper_y]\n"),
     "[stepper_y] rotation_distance is required"),
    (lambda t: t.replace("[stepper_z]\nrotation_distance: 8\nmicrosteps: 16\n", ""),
     "[stepper_z] section is required"),
    (lambda t: t.replace("[stepper_y]\nrotation_distance: 40\nmicrosteps: 16",
                         "[stepper_y]\nrotation_distance: 40\nmicrosteps: 16x"),
     "[stepper_y] microsteps: not an integer: '16x'"),
    (lambda t: t.replace("[stepper_y]\n", "[stepper_y]\nfull_steps_per_rotation: 201\n"),
     "[stepper_y] full_steps_per_rotation: must be a multiple of 4, got 201"),
    (lambda t: t.replace("[stepper_y]\n", "[stepper_y]\ngear_ratio: 3-1\n"),
     "[stepper_y] gear_ratio: expected 'a:b' pairs separated by commas, got '3-1'"),
    (lambda t: t + "[extruder]\nrotation_distance: 33.5\nmicrosteps: 16\nfilament_diameter: 1.75\n",
     "[extruder] nozzle_diameter is required"),
    (lambda t: t + "[extruder]\nrotation_distance: 33.5\nmicrosteps: 16\nnozzle_diameter: 0.4\n",
     "[extruder] filament_diameter is required"),
    (lambda t: t + "[gcode_arcs]\nresolution: 0\n", "[gcode_arcs] resolution: must be above 0, got 0"),
    (lambda t: "stray: 1\n" + t, "'stray: 1' is outside any [section]"),
    (lambda t: t + "this line has no separator\n", "[stepper_z]: expected 'key: value'"),
    (lambda t: t + "[include nothere.cfg]\n", "[include nothere.cfg]: no such file"),
    (lambda t: t + "[include printer.cfg]\n", "[include printer.cfg]: recursive include"),
    (lambda t: t + "#*# <---------------------- SAVE_CONFIG ---------------------->\nmax_accel: 1\n",
     "a line after the SAVE_CONFIG marker must start with '#*#'"),
    (lambda t: t.replace("max_velocity: 300", "max_velocity: 300\n[include empty/*.cfg]\nmax_accel: 5"),
     "'max_accel: 5' is outside any [section]"),
]


@pytest.mark.parametrize("edit,message", KLIPPER_ERRORS, ids=[str(i) for i in range(len(KLIPPER_ERRORS))])
def test_klipper_errors(tmp_path, edit, message):
    path = write(tmp_path, "printer.cfg", edit(minimal()))
    with pytest.raises(ConfigError) as err:
        load_klipper_config(path)
    msg = str(err.value)
    assert re.fullmatch(re.escape(path) + r"(:\d+)?: " + re.escape(message) + ".*", msg), msg


def test_klipper_error_line_points_at_the_value(tmp_path):
    text = minimal().replace("max_velocity: 300", "max_velocity: 300\nmax_z_accel: 0")
    path = write(tmp_path, "printer.cfg", text)
    with pytest.raises(ConfigError) as err:
        load_klipper_config(path)
    assert err.value.line == text.splitlines().index("max_z_accel: 0") + 1


def test_klipper_error_in_included_file_names_that_file(tmp_path):
    inc = write(tmp_path, "limits.cfg", "# limits\n[printer]\nmax_accel: 3k\n")
    path = write(tmp_path, "printer.cfg", minimal() + "[include limits.cfg]\n")
    with pytest.raises(ConfigError) as err:
        load_klipper_config(path)
    assert str(err.value) == f"{inc}:3: [printer] max_accel: not a number: '3k'"


def test_klipper_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_klipper_config(str(tmp_path / "printer.cfg"))


# ============================================================================ machine_from_args

def test_machine_from_args_default_is_klipper_preset():
    assert_same_machine(machine_from_args(argparse.Namespace()), load_machine("klipper"), skip=())
    ns = argparse.Namespace(machine=None, klipper_config=None, flavor=None)
    assert_same_machine(machine_from_args(ns), load_machine("klipper"), skip=())
    # only the default may take a CNC program's flavor (gcode/dialect.py); a named machine or flavor is kept
    assert machine_from_args(ns).auto_flavor and not load_machine("klipper").auto_flavor
    assert not machine_from_args(argparse.Namespace(machine="klipper")).auto_flavor
    assert not machine_from_args(argparse.Namespace(flavor="marlin")).auto_flavor


def test_machine_from_args_sources_and_flavor_override():
    m = machine_from_args(argparse.Namespace(machine="grbl", flavor="linuxcnc"))
    assert (m.flavor, m.junction_policy) == ("linuxcnc", "junction-deviation")
    m = machine_from_args(argparse.Namespace(klipper_config=str(DATA / "max_accel_to_decel.cfg"), flavor="marlin"))
    assert (m.flavor, m.junction_policy, m.minimum_cruise_ratio) == ("marlin", "klipper", 0.75)
    with pytest.raises(ConfigError, match="not both"):
        machine_from_args(argparse.Namespace(machine="grbl", klipper_config="x.cfg"))
    with pytest.raises(ConfigError, match="--flavor: unknown value 'sailfish'"):
        machine_from_args(argparse.Namespace(flavor="sailfish"))


def test_machine_from_args_does_not_share_state():
    """Two calls give independent machines (the planner may change a machine's limits)."""
    a = machine_from_args(argparse.Namespace())
    a.axes["z"].max_velocity = 1.0
    assert machine_from_args(argparse.Namespace()).axes["z"].max_velocity == 15.0
