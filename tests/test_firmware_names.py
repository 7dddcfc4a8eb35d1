"""``klipper`` and ``linuxcnc`` as firmware models (issue 21): selectable wherever a firmware is (machine TOML,
``--firmware``, ``Machine(firmware=)``, ``load_machine(firmware=)``, the klipper preset and the printer.cfg /
mill.ini readers), planning exactly as their policy does (bit for bit, and against the firmware's own reference
totals), a conflicting policy an error naming the file, and the summary naming the model and the firmware
version it reproduces."""
from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

import gcodeplan as gp
from conftest import shared_path
from gcodeplan.config import load_klipper_config, load_machine
from gcodeplan.config.linuxcnc import load_linuxcnc_ini
from gcodeplan.errors import ConfigError
from gcodeplan.machine import Machine

KLIPPER = ("reference", "klipper")
LINUXCNC = ("reference", "linuxcnc")


def _klipper_cfg() -> Machine:
    return load_klipper_config(str(shared_path(*KLIPPER, "cartesian_corpus.cfg")))


def _mill() -> Machine:
    return load_linuxcnc_ini(str(shared_path(*LINUXCNC, "config", "mill.ini")))


def _same_plan(a, b) -> None:
    """Two estimates of one program: equal to the last bit, per line and in total."""
    (la, ta), (lb, tb) = a.line_times(), b.line_times()
    assert np.array_equal(la, lb) and np.array_equal(ta, tb)
    assert a.total_time_s == b.total_time_s


# ----------------------------------------------------------------------------- the model is its policy
@pytest.mark.parametrize("name", ["b_square", "c_circle200"])
def test_klipper_firmware_plans_as_klipper_does(name):
    """The printer.cfg reader and the klipper preset name firmware "klipper"; the plan is the klipper policy's
    to the last bit, and Klipper's own total (v0.13.0-730, reference synthetic runs) to 1e-9."""
    path = str(shared_path(*KLIPPER, "synthetic", name + ".gcode"))
    ref = json.loads(shared_path(*KLIPPER, "synthetic", "times.json").read_text())[name + ".gcode"]["total_time_s"]
    cfg = _klipper_cfg()
    assert (cfg.firmware, cfg.junction_policy) == ("klipper", "klipper")
    assert gp.load_machine("klipper").firmware == "klipper"
    model = gp.estimate(path, cfg)
    policy = gp.estimate(path, replace(cfg, firmware="generic"))
    _same_plan(model, policy)
    assert (model.firmware, policy.firmware) == ("klipper", "")
    assert model.total_time_s == pytest.approx(ref, rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("stem", ["val_square_g64", "val_diag_g61"])
def test_linuxcnc_firmware_plans_as_linuxcnc_does(stem):
    """mill.ini's machine is firmware "linuxcnc"; ``Machine(firmware="linuxcnc")`` takes the linuxcnc policy;
    both plan as the policy does, bit for bit, and within one servo cycle of LinuxCNC 2.9's own run."""
    path = str(shared_path(*LINUXCNC, "validation", "programs", stem + ".ngc"))
    ref = json.loads(shared_path(*LINUXCNC, "validation", "times.json").read_text())[stem]["total_time_noidle_s"]
    mill = _mill()
    assert (mill.firmware, mill.junction_policy) == ("linuxcnc", "linuxcnc")
    model = gp.estimate(path, mill)
    policy = gp.estimate(path, replace(mill, firmware="generic"))
    _same_plan(model, policy)
    assert (model.firmware, policy.firmware, policy.policy) == ("linuxcnc", "", "linuxcnc")
    assert abs(model.total_time_s - ref) <= 0.001 + 1e-9          # one 1 ms servo cycle
    # the library's own Machine: firmware "linuxcnc" alone brings the policy along
    bare = Machine(firmware="linuxcnc", flavor="linuxcnc", max_velocity=mill.max_velocity, max_accel=mill.max_accel,
                   axes=mill.axes, linuxcnc=mill.linuxcnc)
    assert bare.junction_policy == "linuxcnc"
    _same_plan(gp.estimate(path, bare), model)


def test_firmware_option_and_load_machine_equal_the_policy(capsys):
    """``--firmware linuxcnc`` / ``load_machine(firmware="linuxcnc")`` plan as ``--policy linuxcnc`` does (bit for
    bit) and say so; ``--firmware klipper`` on the marlin machine plans as ``--policy klipper`` there."""
    from gcodeplan.cli import main

    program = ["G21 G90", "G1 X10 Y0 F3000", "G1 X10 Y10", "G1 X0 Y10", "G1 X0 Y0", "G0 Z5"]
    ini = str(shared_path(*LINUXCNC, "config", "mill.ini"))
    m = gp.load_machine(linuxcnc_ini=ini, firmware="generic")
    assert (m.firmware, m.junction_policy) == ("generic", "linuxcnc")
    back = gp.load_machine(linuxcnc_ini=ini, firmware="linuxcnc")
    assert (back.firmware, back.junction_policy) == ("linuxcnc", "linuxcnc")
    model = gp.estimate(program, back)
    policy = gp.estimate(program, replace(m, junction_policy="klipper"), "linuxcnc")
    _same_plan(model, policy)
    assert model.firmware == "linuxcnc" and policy.firmware == ""
    mk = gp.load_machine("marlin", firmware="klipper")
    assert (mk.firmware, mk.junction_policy) == ("klipper", "klipper")
    _same_plan(gp.estimate(program, mk), gp.estimate(program, gp.load_machine("marlin", firmware="generic"), "klipper"))

    shared = str(shared_path(*KLIPPER, "synthetic", "b_square.gcode"))
    out = {}
    for args in (["--machine", "marlin", "--firmware", "klipper"], ["--machine", "marlin", "--firmware", "generic",
                                                                   "--policy", "klipper"], []):
        assert main(["estimate", shared, "--json", "-q", *args]) == 0
        out[" ".join(args[3:])] = json.loads(capsys.readouterr().out)
    assert out["klipper"]["total_time_s"] == out["generic --policy klipper"]["total_time_s"]
    assert out["klipper"]["firmware"] == "klipper" and out["generic --policy klipper"]["firmware"] == ""
    assert out[""]["firmware"] == "klipper"          # the default machine, the klipper preset
    assert main(["estimate", shared, "--json", "-q", "--firmware", "linuxcnc", "--linuxcnc-ini", ini]) == 0
    assert json.loads(capsys.readouterr().out)["firmware"] == "linuxcnc"


# ----------------------------------------------------------------------------- conflicts
def test_a_conflicting_policy_is_an_error_naming_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('firmware = "klipper"\n[junction]\npolicy = "blend"\n')
    with pytest.raises(ConfigError, match=r"bad\.toml.*firmware 'klipper'.*'blend'"):
        load_machine(str(bad))
    bad2 = tmp_path / "bad2.toml"
    bad2.write_text('base = "klipper"\nfirmware = "linuxcnc"\n[junction]\npolicy = "klipper"\n')
    with pytest.raises(ConfigError, match=r"bad2\.toml.*firmware 'linuxcnc'.*'klipper'"):
        load_machine(str(bad2))
    with pytest.raises(ConfigError, match="firmware 'linuxcnc'"):
        Machine(firmware="linuxcnc", junction_policy="klipper")
    with pytest.raises(ConfigError, match="firmware 'klipper'"):
        replace(gp.load_machine("klipper"), junction_policy="junction-deviation")
    ok = tmp_path / "ok.toml"
    ok.write_text('firmware = "linuxcnc"\n[junction]\npolicy = "linuxcnc"\n')
    assert load_machine(str(ok)).junction_policy == "linuxcnc"


def test_over_a_base_naming_one_takes_the_other_along(tmp_path):
    """``firmware = "linuxcnc"`` over the klipper preset plans with the linuxcnc policy; ``policy = "blend"``
    over it leaves Klipper (which has no blend): the firmware becomes generic. A round trip keeps both."""
    from gcodeplan.config import machine_to_toml

    fw = tmp_path / "fw.toml"
    fw.write_text('base = "klipper"\nfirmware = "linuxcnc"\n')
    pol = tmp_path / "pol.toml"
    pol.write_text('base = "klipper"\n[junction]\npolicy = "blend"\n')
    alone = tmp_path / "alone.toml"
    alone.write_text('firmware = "linuxcnc"\n')
    assert (load_machine(str(fw)).firmware, load_machine(str(fw)).junction_policy) == ("linuxcnc", "linuxcnc")
    assert (load_machine(str(pol)).firmware, load_machine(str(pol)).junction_policy) == ("generic", "blend")
    assert load_machine(str(alone)).junction_policy == "linuxcnc"
    for m in (load_machine(str(fw)), _klipper_cfg()):
        back = tmp_path / "back.toml"
        back.write_text(machine_to_toml(m))
        assert load_machine(str(back)) == m


# ----------------------------------------------------------------------------- the summary
def test_summary_names_model_and_version():
    """Klipper's version is the reference run's (its README: git hash and describe string); "generic" and a
    policy the firmware does not have name the policy; --jerk (S-curves) is no firmware's planning."""
    readme = shared_path(*KLIPPER, "README.md").read_text()
    git, describe = re.search(r'git ([0-9a-f]{7,}), "(v[0-9][^"]*)"', readme).groups()
    program = ["G1 X10 F3000", "G1 X10 Y10"]
    est = gp.estimate(program)
    line = est.to_text().splitlines()[1]
    assert line == f"  machine klipper-reference-cartesian, firmware klipper (Klipper {describe}, git {git})"
    d = est.to_json()
    assert (d["firmware"], d["firmware_version"], d["policy"]) == ("klipper", f"Klipper {describe}, git {git}",
                                                                    "klipper")
    mill = gp.load_machine(linuxcnc_ini=str(shared_path(*LINUXCNC, "config", "mill.ini")))
    assert gp.estimate(program, mill).to_text().splitlines()[1].endswith(", firmware linuxcnc (LinuxCNC 2.9)")
    blend = gp.estimate(program, None, "blend")
    assert blend.to_text().splitlines()[1] == "  machine klipper-reference-cartesian, policy blend"
    assert (blend.to_json()["firmware"], blend.to_json()["firmware_version"]) == ("", "")
    assert gp.estimate(program, None, jerk=20000.0).to_text().splitlines()[1].endswith(", policy klipper")
    generic = gp.estimate(program, gp.load_machine(firmware="generic"))
    assert generic.to_text().splitlines()[1].endswith(", policy klipper")


@pytest.mark.parametrize("preset,firmware,version", [
    ("marlin", "marlin-2.1.2", "Marlin 2.1.2.4"), ("marlin-bugfix", "marlin-bugfix", "Marlin bugfix-2.1.x (2024-07-30)"),
    ("grbl", "grbl-1.1", "grbl 1.1h")])
def test_summary_names_the_firmware_version_of_each_model(preset, firmware, version):
    """The version each reference measured (their READMEs: Marlin 2.1.2.4, bugfix-2.1.x of 2024-07-30, grbl
    1.1h); the same machine with firmware "generic" names its policy."""
    program = ["G21", "G90", "G1 X10 F600", "G1 X10 Y10"]
    est = gp.estimate(program, preset)
    assert est.to_text().splitlines()[1].endswith(f", firmware {firmware} ({version})")
    assert est.to_json()["firmware_version"] == version
    generic = gp.estimate(program, gp.load_machine(preset, firmware="generic"))
    assert generic.to_text().splitlines()[1].endswith(f", policy {generic.policy}") and generic.firmware == ""


def test_policy_models_keep_no_g92_e_positions():
    """Only the firmware models with their own planner take the G92 E positions (Marlin resets its E there);
    Klipper and LinuxCNC keep none, so memory stays bounded on a file of G92 E0 lines."""
    from gcodeplan.gcode.reader import GcodeReader

    lines = ["M83", "G1 X1 E1 F600", "G92 E0"] * 50
    for preset, kept in (("klipper", 0), ("marlin", 50)):
        reader = GcodeReader(lines, gp.load_machine(preset))
        for _ in reader.batches():
            pass
        assert len(reader.interp.e_position_sets) == kept, preset
