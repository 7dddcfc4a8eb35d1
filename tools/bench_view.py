"""``python tools/bench.py view [--files F ...] [--repeat N]``

The viewer's three targets, measured in one run per file (issue 12):

* page size ≤ 25 MB;
* ``gcodeplan view`` wall time ≤ 3× ``gcodeplan estimate``'s on the same file (each a fresh process, as a
  user runs them: start-up and numba's cached kernels included; best of ``--repeat``, after a warm-up);
* ready (first draw done, ``data-gcodeplan-ready`` set) ≤ 2 s in headless Chromium (Debian's
  ``/usr/bin/chromium`` driven by Playwright): from navigation start to the attribute, as the page
  itself measures it (``performance.now()`` when ready), best of ``--repeat`` fresh pages.

Default file: the 50 MB corpus file (1.8 M moves).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from bench_estimate import run_rss

REPO = Path(__file__).resolve().parents[1]
CORPUS = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared")) / "gcode"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TARGET_MB, TARGET_RATIO, TARGET_READY_S = 25.0, 3.0, 2.0


def ready_times(page_path: Path, repeat: int) -> list[tuple[float, float, dict]]:
    """(page-measured ready s, wall s from goto to ready, timing dict) for ``repeat`` fresh pages."""
    from playwright.sync_api import sync_playwright

    out = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for _ in range(repeat):
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            t0 = time.perf_counter()
            page.goto(page_path.as_uri())
            page.wait_for_selector("html[data-gcodeplan-ready]", timeout=120_000)
            wall = time.perf_counter() - t0
            timing = page.evaluate("window.gcodeplanView.timing")
            out.append((timing["readyMs"] / 1000.0, wall, timing))
            page.close()
        browser.close()
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="bench.py view")
    ap.add_argument("--files", nargs="*", help="G-code files (default: the 50 MB corpus file)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    files = [Path(f) for f in args.files] if args.files else [CORPUS / "prusaslicer25_plate150_gyroid_big.gcode"]
    missing = [f for f in files if not f.is_file()]
    if missing:
        print(f"no such file: {missing[0]}", file=sys.stderr)
        return 2
    exe = [sys.executable, "-m", "gcodeplan.cli"]
    print("| file | moves | page MB | estimate s | view s | view / estimate | view peak RSS MB "
          "| ready s (page) | ready s (wall) | decode / build / draw ms |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for f in files:
            out = Path(tmp) / (f.stem + ".html")
            run_rss(exe + ["estimate", "-q", "--json", str(f)])          # warm numba's cache
            est = min(run_rss(exe + ["estimate", "-q", "--json", str(f)])[0] for _ in range(args.repeat))
            views = [run_rss(exe + ["view", "-q", str(f), "-o", str(out)]) for _ in range(args.repeat)]
            if any(v[2] != 0 for v in views):
                print(f"view failed on {f}", file=sys.stderr)
                return 1
            view_s = min(v[0] for v in views)
            rss = max(v[1] for v in views)
            mb = out.stat().st_size / 1e6
            ready = ready_times(out, args.repeat)
            best = min(ready, key=lambda r: r[0])
            import re

            moves = int(re.search(r'"n":(\d+)', out.read_text(encoding="utf-8")[:200_000]).group(1))
            tm = best[2]
            print(f"| {f.name} | {moves:,} | {mb:.1f} | {est:.2f} | {view_s:.2f} | {view_s / est:.2f} | {rss:.0f} "
                  f"| {best[0]:.2f} | {min(r[1] for r in ready):.2f} "
                  f"| {tm['decodeMs']:.0f} / {tm['buildMs']:.0f} / {tm['drawMs']:.0f} |")
            ok &= mb <= TARGET_MB and view_s / est <= TARGET_RATIO and best[0] <= TARGET_READY_S
    print(f"\ntargets: page ≤ {TARGET_MB:g} MB, view ≤ {TARGET_RATIO:g}× estimate, ready ≤ {TARGET_READY_S:g} s: "
          + ("met" if ok else "NOT met"))
    return 0
