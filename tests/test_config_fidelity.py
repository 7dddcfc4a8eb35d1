"""The Klipper config reader reads what Klipper reads; the machine TOML writer round-trips every value.

Independent truth for printer.cfg: Python's own configparser set up the way Klipper's
klippy/configfile.py sets it up (RawConfigParser(strict=False, inline_comment_prefixes=(';', '#')),
each line first cut at '#', [include] files read in sorted order where they stand, the SAVE_CONFIG
block found by its exact header, stripped of its '#*# ' prefixes, and its keys dropped where the
regular config sets them). ``reference_sections`` below is that procedure; gcodeplan's
``KlipperCfg`` must give the same sections, keys and values on every shared config, on the test
configs and on generated ones.
"""
from __future__ import annotations

import configparser
import glob
import io
import math
import os
import re
import tomllib

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import REFERENCE, REPO, SHARED_AVAILABLE, shared_path
from gcodeplan.config import KlipperCfg, load_klipper_config, load_machine, machine_to_toml
from gcodeplan.errors import ConfigError
from gcodeplan.machine import AXES, Axis, Machine

DATA = REPO / "tests" / "data" / "config"

AUTOSAVE_HEADER = ("\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
                   "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n")


# ----------------------------------------------------------------------------- Klipper's procedure
def _parser() -> configparser.RawConfigParser:
    return configparser.RawConfigParser(strict=False, inline_comment_prefixes=(";", "#"))


def _append(cp, text: str, name: str) -> None:
    if text:
        cp.read_file(io.StringIO(text), name)


def _parse_with_includes(cp, data: str, filename: str, visited: set) -> None:
    path = os.path.abspath(filename)
    assert path not in visited
    visited.add(path)
    buf = []
    for line in data.split("\n"):
        pos = line.find("#")
        if pos >= 0:
            line = line[:pos]
        mo = configparser.RawConfigParser.SECTCRE.match(line)
        header = mo and mo.group("header")
        if header and header.startswith("include "):
            _append(cp, "\n".join(buf), filename)
            buf = []
            spec = os.path.join(os.path.dirname(filename), header[8:].strip())
            for inc in sorted(glob.glob(spec)):
                with open(inc, encoding="utf-8") as fh:
                    _parse_with_includes(cp, fh.read().replace("\r\n", "\n"), inc, visited)
        else:
            buf.append(line)
    _append(cp, "\n".join(buf), filename)
    visited.remove(path)


def _strip_duplicates(data: str, regular) -> str:
    lines = data.split("\n")
    section = None
    dup = False
    for i, line in enumerate(lines):
        pruned = re.sub("[#;].*$", "", line).rstrip()
        if not pruned:
            continue
        if pruned[0].isspace():
            if dup:
                lines[i] = "#" + lines[i]
            continue
        dup = False
        if pruned[0] == "[":
            section = pruned[1:-1].strip()
            continue
        field = re.sub("[^A-Za-z0-9_].*$", "", pruned)
        if regular.has_section(section) and regular.has_option(section, field):
            dup = True
            lines[i] = "#" + lines[i]
    return "\n".join(lines)


def reference_sections(path) -> dict[str, dict[str, str]]:
    """{section: {key: value}} as Klipper's configfile.py (load_main_config) builds them."""
    with open(path, encoding="utf-8") as fh:
        data = fh.read().replace("\r\n", "\n")
    regular, autosave = data, ""
    pos = data.find(AUTOSAVE_HEADER)
    if pos >= 0:
        regular = data[:pos]
        body = data[pos + len(AUTOSAVE_HEADER):].strip()
        autosave = "\n".join([""] + [line[4:] for line in body.split("\n")] + [""])
    cp = _parser()
    _parse_with_includes(cp, regular, str(path), set())
    _append(cp, _strip_duplicates(autosave, cp), "*AUTOSAVE*")
    return {s: dict(cp.items(s)) for s in cp.sections()}


def ours(path) -> dict[str, dict[str, str]]:
    cfg = KlipperCfg(str(path)).read()
    return {s: {k: v.text for k, v in keys.items()} for s, keys in cfg.sections.items()}


# ----------------------------------------------------------------------------- shared and test configs
# The shared configs by name (under ../shared/reference/), so that a bare clone collects the same tests: there
# they read the vendored copies (tests/data/reference/), and test_the_shared_configs_are_there keeps this list
# equal to what ../shared holds.
SHARED_CONFIGS = ["klipper/cartesian_corpus.cfg", "klipper/corexy_corpus.cfg", "klipper/extensions/delta.cfg",
                  "klipper/extensions/delta_wide.cfg", "klipper/extensions/pa_cartesian.cfg",
                  "klipper/extensions/shaper_cartesian.cfg", "klipper/extensions/shaper_corexy.cfg",
                  "klipper/kinematics/deltesian.cfg", "klipper/kinematics/generic_cartesian.cfg",
                  "klipper/kinematics/hybrid_corexy.cfg", "klipper/kinematics/hybrid_corexz.cfg",
                  "klipper/kinematics/polar.cfg", "klipper/kinematics/rotary_delta.cfg",
                  "klipper/kinematics/winch.cfg"]


def _configs():
    """Test ids that do not depend on where the checkout is: shared/reference/… and tests/data/config/…"""
    return ([f"shared/reference/{c}" for c in SHARED_CONFIGS]
            + [f"tests/data/config/{os.path.basename(p)}" for p in sorted(glob.glob(str(DATA / "*.cfg")))])


def _config_path(name: str):
    if name.startswith("shared/"):
        return shared_path(*name.split("/")[1:])
    return REPO / name


@pytest.mark.parametrize("name", _configs())
def test_every_config_reads_as_klipper_reads_it(name):
    path = _config_path(name)
    assert ours(path) == reference_sections(path)


def test_the_shared_configs_are_there():
    if not SHARED_AVAILABLE:
        pytest.skip("../shared not available")
    found = sorted(os.path.relpath(p, REFERENCE) for p in glob.glob(str(REFERENCE / "**" / "*.cfg"), recursive=True))
    assert found == sorted(SHARED_CONFIGS)


def test_save_config_keys_lose_to_the_regular_config():
    """configfile.py comments out an auto-saved key the regular config (includes too) also sets."""
    m = load_klipper_config(str(DATA / "include_main.cfg"))
    assert m.max_accel == 2000.0                  # MAX_ACCEL: 2000 above; the saved 2500 is dropped
    assert m.axes["z"].home == 0.5                # include_steppers.cfg's 0.5, not the saved 0.735


# ----------------------------------------------------------------------------- comments, by hand
MINIMAL = """\
[printer]
kinematics: cartesian
max_velocity: {v}
max_accel: 3000
[stepper_x]
rotation_distance: 40
microsteps: 16
[stepper_y]
rotation_distance: 40
microsteps: 16
[stepper_z]
rotation_distance: 8
microsteps: 16
"""


@pytest.mark.parametrize("value,expected", [
    ("300#fast", 300.0),            # '#' cuts the line anywhere (configfile.py, before configparser)
    ("300 ;fast", 300.0),           # ';' after whitespace: configparser's inline comment
    ("300\t; fast", 300.0),
    ("300 # fast ; x", 300.0),
    ("  300  ", 300.0),
])
def test_comment_rules(tmp_path, value, expected):
    p = tmp_path / "printer.cfg"
    p.write_text(MINIMAL.format(v=value))
    assert load_klipper_config(str(p)).max_velocity == expected
    assert float(reference_sections(p)["printer"]["max_velocity"]) == expected


def test_semicolon_without_whitespace_is_part_of_the_value_as_in_klipper(tmp_path):
    p = tmp_path / "printer.cfg"
    p.write_text(MINIMAL.format(v="300;fast"))
    assert reference_sections(p)["printer"]["max_velocity"] == "300;fast"     # float() fails in Klipper too
    with pytest.raises(ConfigError) as err:
        load_klipper_config(str(p))
    assert str(err.value) == f"{p}:3: [printer] max_velocity: not a number: '300;fast'"


def test_errors_keep_file_and_line_in_includes(tmp_path):
    (tmp_path / "steppers.cfg").write_text("[stepper_x]\nrotation_distance: 40\nmicrosteps: 16#x\n"
                                           "position_max: 200\nposition_endstop: 250\n")
    main = tmp_path / "printer.cfg"
    main.write_text(MINIMAL.format(v=300).replace("[stepper_x]\nrotation_distance: 40\nmicrosteps: 16\n", "")
                    + "[include steppers.cfg]\n")
    with pytest.raises(ConfigError) as err:
        load_klipper_config(str(main))
    assert str(err.value) == (f"{tmp_path / 'steppers.cfg'}:5: position_endstop in section 'stepper_x' must be "
                              f"between position_min and position_max")


def test_damaged_save_config_block_is_an_error_not_a_silent_difference(tmp_path):
    p = tmp_path / "printer.cfg"
    p.write_text(MINIMAL.format(v=300) + AUTOSAVE_HEADER + "#*# [printer]\n#*#max_accel = 1\n")
    with pytest.raises(ConfigError, match=r"printer\.cfg:19: a line after the SAVE_CONFIG marker must start"):
        load_klipper_config(str(p))


# ----------------------------------------------------------------------------- generated configs
_names = st.text("abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=8).filter(
    lambda s: not s.startswith("include") and s != "DEFAULT")
_values = st.text(st.characters(codec="utf-8", exclude_characters="\n\r#;[]\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029",
                                exclude_categories=("Cs",)), max_size=12).map(str.strip)
_comment = st.sampled_from(["", "#c", " #c", " ;c", "\t; c", "#;", " # a ; b", ";x"])   # ';x' stays in the value


@st.composite
def klipper_config(draw):
    lines = []
    sections = draw(st.lists(_names, min_size=1, max_size=4))
    for sec in sections:
        lines.append(f"[{sec}]" + draw(st.sampled_from(["", " #c", " ;c"])))
        for _ in range(draw(st.integers(0, 4))):
            key = draw(_names)
            sep = draw(st.sampled_from([":", " : ", "=", " = ", ": "]))
            lines.append(f"{key}{sep}{draw(_values)}{draw(_comment)}")
            for _ in range(draw(st.integers(0, 2))):        # continuation lines, blank lines, comment lines
                lines.append(draw(st.sampled_from(["  more", "\tx: y", "", "  #c", "   ", "  ;c"])))
        if draw(st.booleans()):
            lines.append(draw(st.sampled_from(["# comment", "; comment", "", "   "])))
    text = "\n".join(lines) + "\n"
    if draw(st.booleans()):
        saved = [f"[{draw(st.sampled_from(sections + ['saved']))}]"]
        for _ in range(draw(st.integers(1, 3))):
            saved.append(f"{draw(_names)} = {draw(_values)}")
        text = text.rstrip("\n") + AUTOSAVE_HEADER + "\n".join("#*# " + s for s in saved) + "\n#*#\n"
    if draw(st.booleans()):
        text = text.replace("\n", "\r\n")
    return text


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=klipper_config())
def test_generated_configs_read_as_klipper_reads_them(tmp_path, text):
    p = tmp_path / "gen.cfg"
    p.write_bytes(text.encode("utf-8"))
    try:
        want = reference_sections(p)
    except configparser.Error:
        with pytest.raises(ConfigError):
            ours(p)
        return
    assert ours(p) == want


# ----------------------------------------------------------------------------- TOML writer
_floats = st.floats(allow_nan=False)
_pos = st.floats(min_value=1e-3, allow_nan=False, allow_infinity=False)   # the speed/accel floor (docs/machine.md)
_steps = st.floats(min_value=1e-3, max_value=1e6)                          # the steps_per_mm bounds


@st.composite
def machines(draw):
    m = Machine(name=draw(st.text(st.characters(exclude_categories=("Cs",)), max_size=20)),
                kinematics=draw(st.sampled_from(["cartesian", "corexy"])),
                flavor=draw(st.sampled_from(["marlin", "klipper", "reprap", "grbl", "linuxcnc"])),
                junction_policy=draw(st.sampled_from(["junction-deviation", "classic-jerk", "blend",
                                                      "exact-stop"])),
                max_velocity=draw(st.one_of(_pos, st.just(math.inf))),
                max_accel=draw(st.one_of(_pos, st.just(math.inf))),
                accel_print=draw(st.one_of(st.none(), _pos)),
                square_corner_velocity=draw(st.floats(0, 1e6)),
                minimum_cruise_ratio=draw(st.floats(0, 0.999)),
                junction_deviation=draw(st.floats(0, 1e3)))
    for a in AXES:
        lo = draw(st.one_of(st.just(-math.inf), st.floats(-1e6, 1e6)))
        hi = draw(st.one_of(st.just(math.inf), st.floats(-1e6, 1e6)))
        if not hi > lo:
            lo, hi = -math.inf, math.inf
        m.axes[a] = Axis(max_velocity=draw(st.one_of(_pos, st.just(math.inf))), max_accel=draw(_pos),
                         jerk=draw(st.floats(0, 1e3)), steps_per_mm=draw(_steps),
                         home=draw(st.floats(-1e6, 1e6)), position_min=lo, position_max=hi)
    return m


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=machines())
def test_toml_writer_round_trips_every_value(tmp_path, m):
    text = machine_to_toml(m)
    tomllib.loads(text)                          # always valid TOML (tabs, newlines, quotes in the name)
    p = tmp_path / "m.toml"
    p.write_text(text, encoding="utf-8")
    back = load_machine(str(p))
    assert back == m


def test_toml_writer_name_with_control_characters(tmp_path):
    m = Machine(name='tab\there\nnewline "quote" back\\slash \x00\x1f\x7f')
    p = tmp_path / "m.toml"
    p.write_text(machine_to_toml(m), encoding="utf-8")
    assert load_machine(str(p)).name == m.name
