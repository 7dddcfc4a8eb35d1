"""Round trip on the real corpus: counting steps reproduces the planned position.

For every corpus file, the first planned pieces (the first layers) go through
the parser, the planner and the step kernel; at thousands of sampled times the
number of steps taken since the grid was last anchored must equal the planned
stepper position in steps within ½ step (the half-step convention), so within
one step as the issue asks.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path

N_SEGMENTS = 15000
N_SAMPLES = 20000


def _pipeline():
    from gcodeplan.config import load_klipper_config, load_machine
    from gcodeplan.stepper.source import segment_batches

    return load_klipper_config, load_machine, segment_batches


def _first_segments(path, machine, segment_batches):
    segs, resets = [], []
    count = 0
    for seg, reset in segment_batches(str(path), machine):
        segs.append(seg)
        resets.append(reset)
        count += len(seg)
        if count >= N_SEGMENTS:
            break
    seg = np.concatenate(segs)[:N_SEGMENTS]
    return seg, np.concatenate(resets)[:N_SEGMENTS]


def _eval(seg, prefix_w, ts):
    """Stepper position at times ts, with idx of the piece each falls in."""
    idx = np.clip(np.searchsorted(seg["t0"], ts, side="right") - 1, 0, len(seg) - 1)
    tau = ts - seg["t0"][idx]
    r = seg[idx]
    pos = np.zeros(len(ts))
    for ax, w in zip("xyze", prefix_w):
        if w:
            pos += w * (r["p" + ax] + r["v" + ax] * tau + r["a" + ax] * tau ** 2 / 2 + r["j" + ax] * tau ** 3 / 6)
    return pos, idx


def _anchor_pieces(seg, reset, w):
    """Piece indices where the stepper's grid re-anchors (first piece, resets, jumps), as the kernel does."""
    from gcodeplan.stepper.kernel import JUMP_TOL_MM

    p = sum(wi * seg["p" + ax] for ax, wi in zip("xyze", w) if wi)
    dt = seg["dt"]
    end = sum(wi * (seg["p" + ax] + seg["v" + ax] * dt + seg["a" + ax] * dt ** 2 / 2 + seg["j" + ax] * dt ** 3 / 6)
              for ax, wi in zip("xyze", w) if wi)
    jump = np.zeros(len(seg), bool)
    jump[0] = True
    jump[1:] = np.abs(p[1:] - end[:-1]) > JUMP_TOL_MM
    return np.flatnonzero(jump | (reset != 0)), p


CORPUS = ["prusaslicer25_cube20_marlin2.gcode", "cura413_ender3_cylinder30.gcode",
          "prusaslicer25_twisted_vase_spiral.gcode", "prusaslicer25_multi_object_plate_relE.gcode",
          "prusaslicer25_plate150_gyroid_big.gcode", "cncjs_jscut_tball_pocket_laser.gcode",
          "linuxcnc_arcspiral.ngc", "linuxcnc_plasmatest.ngc", "linuxcnc_stellabee1.ngc"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CORPUS)
def test_steps_reproduce_position_on_first_layers(name):
    load_klipper_config, load_machine, segment_batches = _pipeline()
    path = shared_path("gcode", name)
    # any plan will do: the reference corexy printer (CNC files planned cartesian, with their own dialect)
    machine = load_klipper_config(str(shared_path("reference", "klipper", "corexy_corpus.cfg")))
    if name.endswith(".ngc"):
        machine.kinematics = "cartesian"
        machine.flavor = "linuxcnc"
    from gcodeplan.kinematics import rails_for
    from gcodeplan.stepper.generate import generate_steps

    seg, reset = _first_segments(path, machine, segment_batches)
    rails = rails_for(machine)
    steps = generate_steps(seg, rails=rails, reset=reset)
    t_end = seg["t0"][-1] + seg["dt"][-1]
    rng = np.random.default_rng(0)
    ts = np.sort(np.concatenate([rng.uniform(0, t_end, N_SAMPLES), seg["t0"] + 0.5 * seg["dt"]]))
    moved = 0
    for rail in rails:
        t, d = steps[rail.name]
        moved += len(t)
        cum = np.concatenate(([0], np.cumsum(d, dtype=np.int64)))
        anchors, p_start = _anchor_pieces(seg, reset, rail.weights)
        pos, idx = _eval(seg, rail.weights, ts)
        # last anchor at or before each sample's piece; steps counted from that piece's start
        k = anchors[np.searchsorted(anchors, idx, side="right") - 1]
        n_since = cum[np.searchsorted(t, ts, side="right")] - cum[np.searchsorted(t, seg["t0"][k], side="left")]
        err = np.abs(n_since - (pos - p_start[k]) * rail.steps_per_mm)
        assert np.max(err) <= 0.5 + 1e-6, f"{rail.name}: off by {np.max(err):.3f} steps at t = {ts[np.argmax(err)]}"
    assert moved > 1000
