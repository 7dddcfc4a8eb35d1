#!/usr/bin/env python3
"""Our speed (linuxcnc policy) over LinuxCNC's 1 ms velocity trace for one window of each shared program:
``python tools/plot_linuxcnc.py`` writes docs/images/linuxcnc_<stem>.png."""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
REF = ROOT.parent / "shared" / "reference" / "linuxcnc"
# (stem of the reference trace, program, window start s, window end s; on LinuxCNC's time without its idle cycles)
WINDOWS = [
    ("linuxcnc_plasmatest_g64", ROOT / "gcode_samples" / "linuxcnc_plasmatest.ngc", 2.4, 5.6),
    ("linuxcnc_plasmatest_G64P0.0254-on-line1_speedup10",
     REF / "validation" / "programs" / "linuxcnc_plasmatest_G64P0254_line1.ngc", 12.5, 16.0),
    ("linuxcnc_plasmatest_g61", REF / "programs" / "variants" / "linuxcnc_plasmatest_g61.ngc", 14.5, 17.0),
    ("linuxcnc_arcspiral_g64", ROOT / "gcode_samples" / "linuxcnc_arcspiral.ngc", 0.0, 4.0),
    ("linuxcnc_stellabee1_first20000_g64", REF / "programs" / "linuxcnc_stellabee1_first20000.ngc", 40.0, 44.0),
    ("linuxcnc_stellabee1_first20000_g64", REF / "programs" / "linuxcnc_stellabee1_first20000.ngc", 1.9, 2.7),
]


def _without_idle(d) -> tuple[np.ndarray, np.ndarray]:
    """LinuxCNC's trace (t, v) with its queue-empty cycles (program line 0 between moves: task's latency at
    M3/M5/M6..., not planning) cut out, so that its clock is the one the noidle totals use."""
    t, v, line = d["t"], d["v"], d["line"]
    idle = line == 0
    first = int(np.argmax(line > 0))
    idle[:first] = False
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.001
    keep = ~idle
    return (t - np.cumsum(idle) * step)[keep], v[keep]


def main() -> int:
    sys.path.insert(0, str(ROOT / "src"))
    from gcodeplan.gcode.reader import read_moves
    from gcodeplan.config.linuxcnc import load_linuxcnc_ini
    from gcodeplan.planner.linuxcnc import run_linuxcnc

    machine = load_linuxcnc_ini(str(REF / "config" / "mill.ini"))
    out_dir = ROOT / "docs" / "images"
    out_dir.mkdir(parents=True, exist_ok=True)
    written: set[Path] = set()
    for stem, program, t0, t1 in WINDOWS:
        trace = REF / ("validation/velocity" if "speedup10" in stem else "velocity") / f"{stem}.npz"
        if not trace.exists() or not program.exists():
            print(f"skip {stem}: missing data")
            continue
        d = np.load(trace)
        moves, reader = read_moves(str(program), machine)
        run = run_linuxcnc(moves, reader.limits, machine)
        fig, ax = plt.subplots(figsize=(10, 3.6))
        t_ref, v_ref = _without_idle(d)
        k = (t_ref >= t0) & (t_ref <= t1)
        ax.plot(t_ref[k], v_ref[k], color="0.6", lw=2.5, label="LinuxCNC 2.9 (1 ms samples)")
        t = run.times()
        k2 = (t >= t0) & (t <= t1)
        ax.plot(t[k2], run.speed()[k2], color="tab:red", lw=0.9, label="gcodeplan --policy linuxcnc")
        ax.set_xlabel("time (s; LinuxCNC's without its queue-empty idle cycles)")
        ax.set_ylabel("path speed (mm/s)")
        ax.set_title(f"{stem}: ours {run.total_time:.3f} s total")
        ax.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        name = stem.replace("linuxcnc_", "").replace("-on-line1_speedup10", "").replace(".", "")
        target = out_dir / f"linuxcnc_{name}.png"
        if target in written:         # a second window of the same run
            target = out_dir / f"linuxcnc_{name}_{t0:g}s.png"
        written.add(target)
        fd, tmp = tempfile.mkstemp(suffix=".png", dir=out_dir)
        os.close(fd)
        fig.savefig(tmp, dpi=110)
        plt.close(fig)
        os.replace(tmp, target)
        print(target)
    return 0


if __name__ == "__main__":
    sys.exit(main())
