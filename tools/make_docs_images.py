#!/usr/bin/env python3
"""Regenerate the README's pictures (docs/images/*.png): one of each plot kind for a corpus file.

    python tools/make_docs_images.py [--file gcode_samples/prusaslicer25_cube20_marlin2.gcode] [--layer 3]

Uses the same functions as ``gcodeplan plot`` (planned from the file's start with the klipper preset).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default=str(REPO / "gcode_samples" / "prusaslicer25_cube20_marlin2.gcode"))
    ap.add_argument("--layer", type=int, default=3, help="layer drawn by the velocity, axes and path pictures")
    ap.add_argument("--machine", default="klipper", help="machine preset or TOML file")
    ap.add_argument("--out", default=str(REPO / "docs" / "images"))
    args = ap.parse_args(argv)

    from gcodeplan.config import load_machine
    from gcodeplan.report import plots
    from gcodeplan.commands.plot import Selection, load_layer_times, load_window

    machine = load_machine(args.machine)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    win, _ = load_window(args.file, machine, Selection(layer=args.layer))
    times, reader = load_layer_times(args.file, machine)
    name = Path(args.file).name
    figs = {
        "plot_velocity.png": plots.plot_velocity(win),
        "plot_axes.png": plots.plot_axes(win, machine),
        "plot_path.png": plots.plot_path(win),
        "plot_layers.png": plots.plot_layers(times, list(reader.features), list(reader.layer_z),
                                             title=f"{name}: time per layer"),
    }
    for fname, fig in figs.items():
        plots.save_png(fig, out / fname)
        print(out / fname)
    print(f"done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
