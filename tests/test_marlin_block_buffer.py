"""A Marlin build's BLOCK_BUFFER_SIZE is the Marlin model's planner ring: read from Configuration_adv.h or a machine
file's ``marlin_block_buffer``, a value Marlin would not build (not a power of 2) is an error naming the line.

The truth for the plumbing: the estimate of a machine with N blocks equals the Marlin model run directly with
``buffer_blocks=N`` (tests/test_marlin_ideal.py checks the model's buffer against a full look-ahead planner),
and differs from the 16-block default where the buffer matters (4 blocks on a circle of short chords).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import gcodeplan as gp
from conftest import SAMPLES
from gcodeplan.errors import ConfigError
from gcodeplan.gcode.reader import read_moves
from gcodeplan.planner.marlin import run_marlin
from test_marlin_config import ADV, _load, _pair

SLICER = SAMPLES / "c_circle200.gcode"       # 200 short chords: the buffer matters


def _model_total(machine, blocks: int) -> float:
    moves, reader = read_moves(str(SLICER), machine)
    plan, _ = run_marlin(moves, reader.limits, machine, buffer_blocks=blocks)
    return float(np.max(plan["t_start"] + plan["duration"]))


@pytest.mark.parametrize("blocks", [4, 16, 64])
def test_the_estimate_runs_the_machines_buffer(blocks):
    machine = replace(gp.load_machine("marlin-2.1.2"), marlin_block_buffer=blocks)
    total = gp.estimate(str(SLICER), machine).total_time_s
    assert total == pytest.approx(_model_total(machine, blocks), rel=1e-12)


def test_four_blocks_are_slower_than_sixteen():
    machine = gp.load_machine("marlin-2.1.2")
    assert machine.marlin_block_buffer == 16
    t16 = gp.estimate(str(SLICER), machine).total_time_s
    t4 = gp.estimate(str(SLICER), replace(machine, marlin_block_buffer=4)).total_time_s
    assert t4 > t16 * 1.05          # 6.17 s against 5.72 s


def test_configuration_adv_block_buffer_size_is_read(tmp_path):
    adv = ADV.replace("#if ALL(HAS_MEDIA, DIRECT_STEPPING)\n  #define BLOCK_BUFFER_SIZE  8\n#elif HAS_MEDIA\n"
                      "  #define BLOCK_BUFFER_SIZE 16\n#else\n  #define BLOCK_BUFFER_SIZE 16\n#endif",
                      "#define BLOCK_BUFFER_SIZE 64")
    assert "#define BLOCK_BUFFER_SIZE 64" in adv
    m, warned = _load(_pair(tmp_path, adv=adv))
    assert m.marlin_block_buffer == 64
    assert not any("BLOCK_BUFFER_SIZE" in w for w in warned), warned
    m16, warned16 = _load(_pair(tmp_path, adv=ADV, folder="shipped"))       # Marlin's shipped #if HAS_MEDIA block: 16, quiet
    assert m16.marlin_block_buffer == 16 and not any("BLOCK_BUFFER_SIZE" in w for w in warned16), warned16


def test_a_block_buffer_marlin_would_not_build_is_an_error(tmp_path):
    adv = ADV.replace("#else\n  #define BLOCK_BUFFER_SIZE 16\n#endif", "#else\n  #define BLOCK_BUFFER_SIZE 16\n"
                      "#endif\n#undef BLOCK_BUFFER_SIZE\n#define BLOCK_BUFFER_SIZE 24")
    with pytest.raises(ConfigError, match="BLOCK_BUFFER_SIZE 24: must be a power of 2") as err:
        gp.load_machine(str(_pair(tmp_path, adv=adv)))
    assert "Configuration_adv.h" in str(err.value) and err.value.line is not None


@pytest.mark.parametrize("value, ok", [(32, True), (3, False), (0, False), ("16", False)])
def test_machine_file_key(tmp_path, value, ok):
    path = tmp_path / "m.toml"
    path.write_text(f'base = "marlin-2.1.2"\nmarlin_block_buffer = {value!r}\n'.replace("'", '"'))
    if ok:
        assert gp.load_machine(str(path)).marlin_block_buffer == value
    else:
        with pytest.raises(ConfigError, match="marlin_block_buffer"):
            gp.load_machine(str(path))
