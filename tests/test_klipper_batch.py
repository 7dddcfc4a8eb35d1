"""Klipper's batch-mode step-generation windows (gcodeplan.stepper.klipper_batch) against the windows real Klipper
recorded (../shared/reference/klipper/compression: every steppersyncmgr_gen_steps call of its corexy runs), and the
kinematics reference's angle motors on the cube, which need them."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.config import load_klipper_config
from gcodeplan.stepper.klipper_batch import (KLIPPER_BATCH_T, _MotionQueuing, batch_flush_times,
                                              klipper_batch_flush_times, line_end_offsets, position_set_lines)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import compare_kinematics as ck  # noqa: E402

CUBE = "prusaslicer25_cube20_marlin2"


def recorded(name: str) -> np.ndarray:
    """Klipper's window ends (s from the first move's start), the final flush (its last two calls) left out."""
    z = np.load(shared_path("reference", "klipper", "compression", f"{name}_corexy_queue_step.npz"))
    return (z["step_gen_time_s"] - z["first_move_print_time_s"])[:-2]


def corexy():
    return load_klipper_config(str(shared_path("reference", "klipper", "corexy_corpus.cfg")))


def test_timer_jumps_after_100_windows():
    """Hand-worked: need_flush_time 40 s, nothing flushed yet. The timer stays 1.5 s behind (38.5 s): 101 windows of
    0.7 − 0.45 s (0.25 … 25.25 s), then the last whole batch below 38.5 s (25.5 + 52 batches, a hair under 38.5 in
    binary), then one more past it."""
    mq = _MotionQueuing(0.001)
    mq.need_flush_t = 40.0
    mq.flush_timer()
    w = np.array(mq.windows)
    assert len(w) == 103
    assert np.allclose(w[:101], 0.25 * np.arange(1, 102), rtol=0, atol=1e-12)
    assert w[101] == pytest.approx(25.5 + 52 * KLIPPER_BATCH_T, abs=1e-12) and 38.5 - 1e-12 < w[101] < 38.5
    assert w[102] == pytest.approx(38.75, abs=1e-12)
    mq.flush_timer()                     # caught up: nothing more, and the timer waits for the next move
    assert len(mq.windows) == 103 and not mq.timer_due and mq.kick_timer


def test_line_ends_and_position_sets():
    data = b"G28 ; home\nG1 X1\n; x\nSET_KINEMATIC_POSITION X=0\nG1 X2"
    assert list(line_end_offsets(data)) == [11, 17, 21, 48]          # the last line has no newline: never run
    assert position_set_lines(data.decode().split("\n")) == {1, 4}


@pytest.mark.parametrize("name", ["b_square", "d_slicer_like"])
def test_windows_equal_klippers(name):
    """Every window Klipper made for the file, bit for bit: b_square's 8 regular ones, d_slicer_like's 134 and its
    jump from 25.25 s to 33.25 s (its first 4096 bytes hold 34.8 s of motion)."""
    gcode = shared_path("reference", "klipper", "synthetic", f"{name}.gcode")
    w = klipper_batch_flush_times(str(gcode), corexy())
    rec = recorded(name)
    assert len(w) == len(rec) and np.array_equal(w, rec)
    if name == "d_slicer_like":
        assert np.sum(np.diff(w) > 1.0) == 1


def _cube_windows(dropped_extra: int, g28_len: int) -> np.ndarray:
    """The cube's windows with a byte layout of the preprocessed file: each dropped line ``dropped_extra`` bytes
    longer than the original, the G28 line ``g28_len`` bytes (without its newline)."""
    import gcodeplan.api as gp
    from gcodeplan.planner.prepare import prepare

    text = shared_path("gcode", f"{CUBE}.gcode").read_text().split("\n")[:-1]
    m = corexy()
    p = gp.plan(text, m)
    prep = prepare(p.moves, p.limits, m)
    size = np.array([len(ln) + 1 for ln in text])
    for i, ln in enumerate(text):
        words = ln.split(";")[0].split()
        if words and words[0].upper() in ck.KLIPPER_DROPPED:
            size[i] += dropped_extra
        elif words and words[0].upper() == "G28":
            size[i] = g28_len + 1
    return batch_flush_times(np.cumsum(size), p.moves, prep, p.plan, position_set_lines(text))


def test_cube_windows_equal_klippers():
    """All 3921 of Klipper's windows on the whole cube, its 35 jumps included (one per 4096-byte read of ~30 s of
    motion). The compression reference does not store the preprocessed file; its windows fix where the reads end:
    with the dropped lines 10 bytes longer than the original and the G28 line 68 bytes (an offset of 119 bytes over
    lines 515–6931, which the jumps pin to 119–120 bytes), every window is Klipper's. The layout the kinematics
    README gives for its own runs ("; [dropped for Klipper] " + line, 24 bytes) is 64 bytes further and already
    misses the first jump: the windows follow the bytes."""
    rec = recorded(CUBE)
    w = _cube_windows(10, 68)
    assert len(w) == len(rec) == 3921 and np.array_equal(w, rec)
    assert np.sum(np.abs(np.diff(w) - 0.25) > 1e-9) == 35
    other = _cube_windows(24, 35)
    assert not np.array_equal(other[:103], rec[:103])


def _cube_steps(config, windows):
    ck.KIN = shared_path("reference", "klipper", "kinematics")
    ck.SHARED = ck.KIN.parents[2]
    info, ref = ck.reference(CUBE, config)
    m = ck.machine(config)
    lines = ck.source_lines(CUBE, config)
    sched = ck.batch_windows(lines, m) if windows else None
    ours = ck.klipper_steps(lines, m, sched)
    worst = {}
    for motor, (t, d) in ours.items():
        full = info["steps"]["steppers"][motor]
        assert len(t) == full["n_steps"] and int(d.sum(dtype=np.int64)) == full["net_steps"], motor
        k = len(ref[motor])
        assert np.array_equal(d[:k], ref[motor + "_dir"]), motor
        worst[motor] = float(np.max(np.abs(t[:k] - ref[motor]))) if k else 0.0
    return worst


@pytest.mark.slow
@pytest.mark.parametrize("config, motors", [("polar", ("stepper_bed",)),
                                            ("rotary_delta", ("stepper_a", "stepper_b", "stepper_c"))])
def test_cube_angle_motors_within_100ns(config, motors):
    """The cube's angle motors (25 layers): with Klipper's batch windows every step is Klipper's within 100 ns
    (measured ≤ 17 ns); with a window every 0.25 s the slow bed angle and arm b are 310 ns off, where batch mode
    skipped windows (25.25 → 85.5 s and every ~30 s after)."""
    worst = _cube_steps(config, True)
    assert max(worst.values()) < 100e-9, {k: f"{v * 1e9:.1f} ns" for k, v in worst.items()}
    regular = _cube_steps(config, False)
    assert max(regular[mo] for mo in motors) > 100e-9


def test_steps_command_klipper_batch(tmp_path):
    """``gcodeplan steps --klipper-batch`` is ``klippy -i -o``'s output: d_slicer_like on rotary_delta, every step
    of the arm motors within one tick and a half of Klipper's (30 ns); with the regular windows arm b is 74 ns off
    (batch mode jumps from 25.25 s to 33.25 s there)."""
    from gcodeplan.cli import main

    ck.KIN = shared_path("reference", "klipper", "kinematics")
    ck.SHARED = ck.KIN.parents[2]
    info, ref = ck.reference("d_slicer_like", "rotary_delta")     # skips without the kinematics reference
    gcode = shared_path("reference", "klipper", "synthetic", "d_slicer_like.gcode")
    cfg = str(ck.KIN / "rotary_delta.cfg")
    worst = {}
    for opt in ([], ["--klipper-batch"]):
        out = tmp_path / f"s{len(opt)}.npz"
        assert main(["steps", str(gcode), "--klipper-config", cfg, "--sds-filter", "-q", "-o", str(out)] + opt) == 0
        z = np.load(out)
        worst[bool(opt)] = max(float(np.max(np.abs(z[k] - ref[k]))) for k in ("stepper_a", "stepper_b", "stepper_c"))
    assert worst[True] < 30e-9 < 60e-9 < worst[False], worst


def test_steps_command_klipper_batch_refusals(tmp_path, capsys):
    """Windows that follow another plan, or a file it cannot read byte for byte, are refused, not guessed."""
    from gcodeplan.cli import main

    gcode = tmp_path / "a.gcode"
    gcode.write_text("G28\nG1 X10 F3000\n")
    cfg = str(shared_path("reference", "klipper", "corexy_corpus.cfg"))
    assert main(["steps", str(gcode), "--klipper-config", cfg, "--klipper-batch", "--policy", "junction-deviation",
                 "-q", "-o", str(tmp_path / "o.npz")]) != 0
    assert "policy klipper" in capsys.readouterr().err
    assert main(["steps", str(gcode), "--klipper-config", cfg, "--klipper-batch", "--jerk", "1000",
                 "-q", "-o", str(tmp_path / "o.npz")]) != 0
    assert "--klipper-batch" in capsys.readouterr().err


def test_shaping_refused_without_its_scan_window():
    """Input shaping widens Klipper's scan window (kin_flush_delay), which moves every window: refused unless
    given to batch_flush_times."""
    import dataclasses

    from gcodeplan.errors import ConfigError

    m = dataclasses.replace(corexy(), shaper_freq_x=40.0, shaper_freq_y=40.0)
    with pytest.raises(ConfigError, match="kin_flush_delay"):
        klipper_batch_flush_times(b"G28\nG1 X10 F3000\n", m)
    assert len(klipper_batch_flush_times(b"G28\nG1 X10 F3000\n", corexy())) == 1     # the window at G28
