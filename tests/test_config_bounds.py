"""A machine file's absurd numbers are config errors naming the TOML file and key (docs/machine.md "Bounds"),
never a traceback, a message about the G-code file, or a run out of memory."""
from __future__ import annotations

import pytest

import gcodeplan as gp
from gcodeplan.cli import main
from gcodeplan.config import load_machine
from gcodeplan.errors import ConfigError


def _toml(tmp_path, text):
    p = tmp_path / "m.toml"
    p.write_text(text, encoding="utf-8")
    return str(p)


def test_deeply_nested_arrays_are_a_config_error(tmp_path):
    path = _toml(tmp_path, "a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match=r"m\.toml: TOML nested too deeply"):
        load_machine(path)


@pytest.mark.parametrize("key,value,want", [
    ("[toolhead]\nmax_velocity", "1e-300", "toolhead.max_velocity: must be at least 0.001 mm/s (inf = no limit), got 1e-300"),
    ("[toolhead]\nmax_accel", "1e-200", "toolhead.max_accel: must be at least 0.001 mm/s² (inf = no limit), got 1e-200"),
    ("[toolhead]\naccel_print", "5e-320", "toolhead.accel_print: must be at least 0.001 mm/s² (inf = no limit), got 5e-320"),
    ("[toolhead]\nrapid_velocity", "1e-9", "toolhead.rapid_velocity: must be at least 0.001 mm/s"),
    ("[axis.z]\nmax_velocity", "1e-300", "axis.z.max_velocity: must be at least 0.001 mm/s"),
    ("[axis.e]\nmax_accel", "1e-300", "axis.e.max_accel: must be at least 0.001 mm/s²"),
    ("[extruder]\nmax_extrude_only_velocity", "1e-300", "extruder.max_extrude_only_velocity: must be at least"),
    ("[junction]\nmax_jerk", "1e-300", "junction.max_jerk: must be at least 0.001 mm/s³"),
    ("[firmware_retraction]\nretract_speed", "1e-300", "firmware_retraction.retract_speed: must be a finite speed of at least 0.001 mm/s"),
    ("[axis.x]\nsteps_per_mm", "1e12", "axis.x.steps_per_mm: must be a number of steps/mm from 0.001 (a step of 1 m) to 1e6 (a step of 1 nm), got 1000000000000"),
    ("[axis.x]\nsteps_per_mm", "1e-9", "axis.x.steps_per_mm: must be a number of steps/mm from 0.001"),
])
def test_absurd_limits_name_the_toml_file_and_key(tmp_path, key, value, want):
    path = _toml(tmp_path, f"{key} = {value}\n")
    with pytest.raises(ConfigError) as err:
        load_machine(path)
    assert str(err.value).startswith(path + ": " + want), str(err.value)


def test_steps_from_rotation_distance_are_bounded_too(tmp_path):
    path = _toml(tmp_path, "[axis.z]\nrotation_distance = 1e-9\nmicrosteps = 16\n")
    with pytest.raises(ConfigError, match=r"axis\.z\.rotation_distance: .* = 3\.2e\+12 steps/mm; steps_per_mm must be"):
        load_machine(path)


def test_bounds_themselves_are_allowed(tmp_path):
    m = load_machine(_toml(tmp_path, "[toolhead]\nmax_velocity = 0.001\nmax_accel = 0.001\n"
                                     "[axis.z]\nsteps_per_mm = 1e6\n[axis.e]\nsteps_per_mm = 0.001\n"))
    assert m.max_velocity == 0.001 and m.axes["z"].steps_per_mm == 1e6


def test_cli_names_the_toml_not_the_gcode(tmp_path, capsys):
    path = _toml(tmp_path, "[toolhead]\nmax_velocity = 1e-300\n")
    g = tmp_path / "part.gcode"
    g.write_text("G1 X10 F600\n")
    assert main(["estimate", "--machine", path, str(g)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"gcodeplan: {path}: toolhead.max_velocity: must be at least 0.001 mm/s (inf = no limit), got 1e-300"
    assert "part.gcode" not in err


def test_steps_per_mm_at_the_bound_steps_a_short_move(tmp_path):
    # 1e6 steps/mm (the bound) on a 0.01 mm move: 10 000 steps, exactly (each step one nm)
    m = load_machine(_toml(tmp_path, "[axis.x]\nsteps_per_mm = 1e6\n"))
    st = gp.steps(["G1 X0.01 F60"], m)
    assert sorted(len(t) for t, _ in st.values()) == [0, 0, 0, 10_000]
