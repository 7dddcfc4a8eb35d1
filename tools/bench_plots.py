"""``python tools/bench.py plots [--moves N] [--repeat N]``

Drawing a big window: the velocity and path figures of an N-move zigzag window (default 10,000 moves, the
window the plot commands draw at most), built and saved as PNG, best of ``--repeat``. Target: < 2 s each
(the plot issue's figure). The window is the one tests/test_plots.py builds (``zigzag_window``).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 2.0


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py plots")
    ap.add_argument("--moves", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO / "tests"))
    sys.path.insert(0, str(REPO / "src"))
    from test_plots import zigzag_window

    from gcodeplan.report import plots

    win = zigzag_window(args.moves)
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for what, fn in (("velocity", plots.plot_velocity), ("path", plots.plot_path)):
            best = float("inf")
            for _ in range(max(1, args.repeat)):
                t0 = time.perf_counter()
                plots.save_png(fn(win), Path(tmp) / f"{what}.png")
                best = min(best, time.perf_counter() - t0)
            worst = max(worst, best)
            print(f"{what:9s} {args.moves:,} moves: {best:.2f} s (target < {TARGET_S:.0f} s)")
    return 0 if worst < TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
