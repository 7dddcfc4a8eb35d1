"""The interactive viewer (``gcodeplan view``), tested in a real headless Chromium driven by Playwright.

Truth is the plan itself: ``gp.plan(...)`` and its ``sample`` (the planner's own polynomial pieces), the
source file's own lines, and the CLI's exit codes. The browser is Debian's ``chromium``
(``.ci/run`` installs it when missing); these tests skip when it or Playwright is absent.
"""
from __future__ import annotations

import io
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import gcodeplan as gp
from gcodeplan.cli import main
from gcodeplan.report.viewer import _pick_lines
from gcodeplan.schema import KIND_EXTRUDE_ONLY

from conftest import SAMPLES

CHROMIUM = os.environ.get("GCODEPLAN_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
CUBE = SAMPLES / "prusaslicer25_cube20_marlin2.gcode"


# ------------------------------------------------------------------------------------------ no browser
def test_pick_lines_keeps_wanted_lines_crlf_and_unterminated_last():
    data = b"a\r\nbb\nccc\r\n\nlast-no-newline"
    got = _pick_lines(io.BytesIO(data), np.array([2, 3, 5]))
    assert got == b"bb\nccc\nlast-no-newline\n"
    got = _pick_lines(io.BytesIO(data), np.array([1, 4]))
    assert got == b"a\n\n"


def test_pick_lines_across_chunks(monkeypatch):
    import gcodeplan.report.viewer as viewer

    monkeypatch.setattr(viewer, "_READ_CHUNK", 7)  # lines straddle chunk ends
    lines = [f"G1 X{i} Y{2 * i}".encode() for i in range(1, 200)]
    wanted = np.array([1, 2, 50, 51, 52, 198, 199])
    got = viewer._pick_lines(io.BytesIO(b"\n".join(lines) + b"\n"), wanted)
    assert got.split(b"\n")[:-1] == [lines[k - 1] for k in wanted]


@pytest.mark.parametrize("content", [b"", b"; only a comment\nM117 hello\n", b"\x00\x01\x02\xff\xfe" * 400])
def test_empty_or_corrupt_input_is_a_one_line_error(tmp_path, capsys, content):
    src = tmp_path / "bad.gcode"
    src.write_bytes(content)
    out = tmp_path / "view.html"
    rc = main(["view", str(src), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("gcodeplan: ") and err.count("\n") == 1 and "bad.gcode" in err
    assert not out.exists()
    assert not [p for p in os.listdir(tmp_path) if p != "bad.gcode"]   # no temporary file left behind


def test_missing_output_directory_fails_before_planning(tmp_path, capsys):
    rc = main(["view", str(CUBE), "-o", str(tmp_path / "nope" / "v.html")])
    assert rc == 2 and "no such directory" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ browser
@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"{CHROMIUM} not installed (apt-get install chromium)")
    pw = sync_api.sync_playwright().start()
    b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
    yield b
    b.close()
    pw.stop()


class Opened:
    def __init__(self, page, console, requests):
        self.page, self.console, self.requests = page, console, requests

    def js(self, expr, *args):
        return self.page.evaluate(expr, *args)


def open_page(browser, path, width=1400, height=1100) -> Opened:
    page = browser.new_page(viewport={"width": width, "height": height})
    console, requests = [], []
    page.on("console", lambda m: console.append((m.type, m.text)))
    page.on("pageerror", lambda e: console.append(("pageerror", str(e))))
    page.on("request", lambda r: requests.append(r.url))
    page.goto(path.as_uri())
    page.wait_for_selector("html[data-gcodeplan-ready]", timeout=60_000)
    assert page.evaluate("document.documentElement.getAttribute('data-gcodeplan-ready')") == "1", console
    return Opened(page, console, requests)


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    """Viewer pages of small files: name -> (html path, source path, plan), built with the CLI."""
    d = tmp_path_factory.mktemp("viewer")
    made = {}

    def make(name, src, *opts):
        if name not in made:
            out = d / f"{name}.html"
            assert main(["view", str(src), "-o", str(out), "-q", *opts]) == 0
            kw = {}
            if "--jerk" in opts:
                kw["jerk"] = float(opts[opts.index("--jerk") + 1])
            if "--policy" in opts:
                kw["policy"] = opts[opts.index("--policy") + 1]
            made[name] = (out, src, gp.plan(str(src), **kw))
        return made[name]

    return make


def true_speed(plan, times):
    """Path speed from the plan's own pieces: |v_xyz|, or |v_e| for extrude-only moves."""
    _, vel, _, _ = plan.sample(times)
    i = np.searchsorted(plan.plan["t_start"], times, side="right") - 1
    xyz = np.linalg.norm(vel[:, :3], axis=1)
    return np.where(plan.moves["kind"][i] == KIND_EXTRUDE_ONLY, np.abs(vel[:, 3]), xyz), i


def random_inner_times(plan, k, seed):
    """k sorted random times, none within 1e-6 s of a move boundary (where the line changes)."""
    rng = np.random.default_rng(seed)
    t0 = plan.plan["t_start"]
    total = plan.total_time_s
    out = []
    while len(out) < k:
        t = float(rng.uniform(0.0, total))
        j = np.searchsorted(t0, t)
        near = [abs(t - t0[q]) for q in (j - 1, j) if 0 <= q < len(t0)] + [abs(total - t)]
        if min(near) > 1e-6:
            out.append(t)
    return np.sort(np.array(out))


def source_lines(src):
    with open(src, "rb") as fh:
        return [ln.rstrip(b"\r\n").decode("utf-8", "replace") for ln in fh]


def test_page_loads_offline_without_errors(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    assert [m for m in v.console if m[0] in ("error", "pageerror", "warning")] == []
    assert v.requests == [html.as_uri()]          # the page itself, nothing else
    st = v.js("gcodeplanView.state()")
    assert st["moves"] == len(plan.moves)
    assert st["totalTime"] == pytest.approx(plan.total_time_s, abs=1e-9)
    assert st["t0"] == 0 and st["t1"] == pytest.approx(plan.total_time_s, abs=1e-9)
    assert st["points"] > 100 and st["mode"] == "envelope"
    assert st["layer"] == 0 and st["pathSegments"] > 50
    # the whole-print envelope holds every speed of the plan
    assert st["drawn"]["vmax"] == pytest.approx(plan.plan["cruise_v"].max(), abs=1e-6)
    v.page.close()


@pytest.mark.parametrize("name,src,opts", [
    ("cube", CUBE, ()),
    ("cube_scurve", CUBE, ("--jerk", "30000")),
    ("cube_blend", CUBE, ("--policy", "blend")),
    ("bgcode", SAMPLES / "mini_cube_ps2.8.1.bgcode", ()),
])
def test_inspect_at_matches_the_plan(browser, pages, name, src, opts):
    html, src, plan = pages(name, src, *opts)
    v = open_page(browser, html)
    times = random_inner_times(plan, 50, seed=12)
    speed, idx = true_speed(plan, times)
    got = v.js("ts => ts.map(t => gcodeplanView.inspectAt(t))", times.tolist())
    # binary G-code: line numbers and texts are those of its ASCII conversion (PrusaSlicer's export)
    lines = source_lines(SAMPLES / "mini_cube_ps2.8.1_ref.gcode" if src.suffix == ".bgcode" else src)
    for t, s, i, g in zip(times, speed, idx, got):
        assert g["time"] == t
        assert abs(g["speed"] - s) <= 1e-6, (t, g, s)
        assert g["line"] == plan.moves["line"][i]
        assert g["text"] == lines[int(plan.moves["line"][i]) - 1]
        assert g["limit"] == ("feed", "max_velocity", "axis", "extruder", "accel", "cruise_ratio", "junction",
                              "none")[plan.plan["limit"][i]]
        assert g["layer"] == plan.moves["layer"][i]
        f = plan.moves["feature"][i]
        assert g["feature"] == (plan.features[f] if f >= 0 else None)
        assert set(g) >= {"time", "speed", "accel", "line", "text", "feature", "layer", "object", "limit"}
    # inside trapezoid phases the acceleration is the plan's own
    if name == "cube":
        p = plan.plan[idx]
        tau = times - p["t_start"]
        acc = np.where(tau < p["accel_t"], p["accel"],
                       np.where(tau < p["accel_t"] + p["cruise_t"], 0.0, -p["decel"]))
        for a, g in zip(acc, got):
            assert g["accel"] == pytest.approx(a, abs=1e-6)
    v.page.close()


@pytest.mark.parametrize("name,opts", [("cube", ()), ("cube_scurve", ("--jerk", "30000"))])
def test_zoom_to_one_move_draws_the_plans_extremes(browser, pages, name, opts):
    html, _, plan = pages(name, CUBE, *opts)
    p = plan.plan
    full = np.flatnonzero((plan.moves["kind"] <= 1) & (p["accel_t"] > 1e-3) & (p["cruise_t"] > 1e-3) & (p["decel_t"] > 1e-3)
                          & (p["start_v"] != p["end_v"]))
    v = open_page(browser, html)
    for i in full[[0, len(full) // 2, -1]]:
        t0, t1 = float(p["t_start"][i]), float(p["t_start"][i] + p["duration"][i])
        st = v.js("([a, b]) => gcodeplanView.zoomTo(a, b)", [t0, t1])
        assert st["mode"] == "exact"
        d = st["drawn"]
        assert d["vmax"] == pytest.approx(p["cruise_v"][i], abs=1e-6)
        assert d["vmin"] == pytest.approx(min(p["start_v"][i], p["end_v"][i]), abs=1e-6)
        a_lo, a_hi = path_accel_extremes(plan, i)
        assert d["amax"] == pytest.approx(a_hi, abs=1e-6)
        assert d["amin"] == pytest.approx(a_lo, abs=1e-6)
        if not opts:   # trapezoids: the PLAN row's own accelerations
            assert (a_lo, a_hi) == pytest.approx((-p["decel"][i], p["accel"][i]), abs=1e-9)
        # and the plan's own pieces, sampled densely, stay inside what is drawn and reach it
        ts = np.linspace(t0 + 1e-9, t1 - 1e-9, 2001)
        s, _ = true_speed(plan, ts)
        assert s.max() <= d["vmax"] + 1e-6 and s.max() >= d["vmax"] - 1e-3
        assert s.min() >= d["vmin"] - 1e-6 and s.min() <= d["vmin"] + 1e-2
    v.page.close()


def path_accel_extremes(plan, i):
    """(min, max) acceleration along the path of XYZ move i, from the plan's own SEGMENT pieces
    (a + j·τ projected on the move's direction is linear in each piece: its ends are its extremes)."""
    m = plan.moves[i]
    d = np.array([m["x1"] - m["x0"], m["y1"] - m["y0"], m["z1"] - m["z0"]])
    u = d / np.linalg.norm(d)
    segs = plan.segments[plan.segments["move"] == i]
    a0 = sum(segs["a" + ax] * u[k] for k, ax in enumerate("xyz"))
    j = sum(segs["j" + ax] * u[k] for k, ax in enumerate("xyz"))
    vals = np.r_[a0, a0 + j * segs["dt"]]
    return float(vals.min()), float(vals.max())


def _variance(png: bytes) -> float:
    import matplotlib.image as mpimg

    img = mpimg.imread(io.BytesIO(png), format="png")[..., :3]
    return float(img.var())


def test_screenshots_at_three_zoom_levels_are_not_blank(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    i = int(np.argmax(plan.plan["duration"] * (plan.moves["kind"] == 1)))
    layer = int(plan.moves["layer"][i])
    lt = plan.plan["t_start"][plan.moves["layer"] == layer]
    windows = [(0.0, plan.total_time_s), (float(lt[0]), float(lt[-1])),
               (float(plan.plan["t_start"][i]), float(plan.plan["t_start"][i] + plan.plan["duration"][i]))]
    shots = []
    for a, b in windows:
        st = v.js("([a, b]) => gcodeplanView.zoomTo(a, b)", [a, b])
        assert st["t0"] == pytest.approx(a) and st["t1"] == pytest.approx(b)
        v.js("l => gcodeplanView.showLayer(l)", layer)
        tl = v.page.locator("#gpv-timeline").screenshot()
        path = v.page.locator("#gpv-path").screenshot()
        assert _variance(tl) > 1e-3 and _variance(path) > 1e-4
        shots.append(tl)
    assert len(set(shots)) == 3                   # each zoom level draws something different
    v.page.close()


def test_path_click_shows_the_move_on_the_timeline(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    v.js("gcodeplanView.showLayer(5)")
    m = plan.moves
    cand = np.flatnonzero((m["layer"] == 5) & (m["kind"] == 1)
                          & (np.hypot(m["x1"] - m["x0"], m["y1"] - m["y0"]) > 8))
    i = int(cand[len(cand) // 2])
    xy = v.js("i => gcodeplanView.pathPoint(i)", i)      # the middle of that segment on the canvas
    box = v.page.locator("#gpv-path").bounding_box()
    v.page.mouse.click(box["x"] + xy[0], box["y"] + xy[1])
    st = v.js("gcodeplanView.state()")
    t0, t1 = plan.plan["t_start"][i], plan.plan["t_start"][i] + plan.plan["duration"][i]
    assert st["highlight"] == pytest.approx([t0, t1], abs=1e-9)
    assert st["t0"] <= t0 and st["t1"] >= t1 and st["t1"] - st["t0"] < 10 * (t1 - t0) + 0.05
    assert st["mode"] == "exact"
    insp = v.page.locator("#gpv-insp").inner_text()
    assert str(int(m["line"][i])) in insp
    v.page.close()


def test_timeline_selection_highlights_the_toolpath(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    lt = plan.plan["t_start"][plan.moves["layer"] == 4]
    v.js("([a, b]) => gcodeplanView.zoomTo(a, b)", [float(lt[0]), float(lt[-1])])
    v.js("gcodeplanView.showLayer(4)")
    before = v.page.locator("#gpv-path").screenshot()
    over = v.page.locator("#gpv-timeline .u-over").bounding_box()
    y = over["y"] + over["height"] / 2
    v.page.mouse.move(over["x"] + over["width"] * 0.3, y)
    v.page.mouse.down()
    v.page.mouse.move(over["x"] + over["width"] * 0.5, y, steps=5)
    v.page.mouse.up()
    st = v.js("gcodeplanView.state()")
    a, b = st["highlight"]
    span = lt[-1] - lt[0]
    assert a == pytest.approx(lt[0] + 0.3 * span, rel=0.02, abs=0.5)
    assert b == pytest.approx(lt[0] + 0.5 * span, rel=0.02, abs=0.5)
    assert st["t0"] == pytest.approx(a) and st["t1"] == pytest.approx(b)
    assert st["highlighted"] > 0 and st["layer"] == 4
    assert v.page.locator("#gpv-path").screenshot() != before
    v.page.close()


def test_layer_bar_click_and_keyboard(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    st = v.js("gcodeplanView.state()")
    layers = st["layers"]
    k = layers.index(10)
    box = v.page.locator("#gpv-bars").bounding_box()
    geom = v.js("gcodeplanView.barsGeometry()")
    v.page.mouse.click(box["x"] + geom["left"] + (k + 0.5) * geom["bw"], box["y"] + box["height"] / 2)
    st = v.js("gcodeplanView.state()")
    lt = plan.plan["t_start"][plan.moves["layer"] == 10]
    last = np.flatnonzero(plan.moves["layer"] == 10)[-1]
    assert st["layer"] == 10
    assert st["t0"] == pytest.approx(lt[0], abs=1e-9)
    assert st["t1"] == pytest.approx(plan.plan["t_start"][last] + plan.plan["duration"][last], abs=1e-6)
    v.page.locator("#gpv-path").focus()
    v.page.keyboard.press("PageUp")
    assert v.js("gcodeplanView.state().layer") == 11
    v.page.keyboard.press("ArrowDown")
    v.page.keyboard.press("ArrowDown")
    assert v.js("gcodeplanView.state().layer") == 9
    v.page.close()


def test_report_embeds_the_viewer(browser, tmp_path):
    out = tmp_path / "report.html"
    assert main(["report", str(SAMPLES / "d_slicer_like.gcode"), "-o", str(out), "--slowest", "0"]) == 0
    text = out.read_text()
    assert text.index('id="gpv"') < text.index("<table")      # above the tables
    v = open_page(browser, out)
    assert [m for m in v.console if m[0] in ("error", "pageerror")] == []
    plan = gp.plan(str(SAMPLES / "d_slicer_like.gcode"))
    t = random_inner_times(plan, 5, seed=3)
    s, _ = true_speed(plan, t)
    got = v.js("ts => ts.map(t => gcodeplanView.inspectAt(t).speed)", t.tolist())
    assert np.max(np.abs(np.array(got) - s)) <= 1e-6
    v.page.close()


@pytest.mark.slow
def test_corpus_file_page_size_and_load(browser, tmp_path):
    from conftest import shared_path

    src = shared_path("gcode", "prusaslicer25_plate150_gyroid_big.gcode")
    out = tmp_path / "big.html"
    assert main(["view", str(src), "-o", str(out), "-q"]) == 0
    assert out.stat().st_size <= 25_000_000
    v = open_page(browser, out)
    st = v.js("gcodeplanView.state()")
    assert st["moves"] > 1_700_000
    r = v.js("gcodeplanView.inspectAt(50000)")
    lines = source_lines(src)
    assert r["text"] == lines[int(r["line"]) - 1]
    v.page.close()


def test_view_reads_standard_input(tmp_path):
    out = tmp_path / "stdin.html"
    with open(CUBE, "rb") as fh:
        r = subprocess.run([sys.executable, "-m", "gcodeplan.cli", "view", "-", "-o", str(out), "-q"], stdin=fh,
                           capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert 'gpv-meta' in out.read_text()
    assert not [p for p in os.listdir(tmp_path) if p != "stdin.html"]
    assert shutil.which("gcodeplan")


# ------------------------------------------------------------------------------------------ issue 19
def test_pan_and_zoom_out_stay_inside_the_print(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    total = plan.total_time_s
    v.js("([a, b]) => gcodeplanView.zoomTo(a, b)", [total - 30.0, total - 10.0])
    v.page.locator("#gpv-path").focus()
    for _ in range(6):
        v.page.keyboard.press("ArrowRight")
    st = v.js("gcodeplanView.state()")
    assert st["t1"] == pytest.approx(total, abs=1e-9) and st["t1"] - st["t0"] == pytest.approx(20.0, abs=1e-6)
    for _ in range(int(total / 5) + 10):
        v.page.keyboard.press("ArrowLeft")
    st = v.js("gcodeplanView.state()")
    assert st["t0"] == 0 and st["t1"] == pytest.approx(20.0, abs=1e-6)
    for _ in range(30):
        v.page.keyboard.press("-")
    st = v.js("gcodeplanView.state()")
    assert st["t0"] == 0 and st["t1"] == pytest.approx(total, abs=1e-9)
    v.page.close()


def _tick_labels(v):
    """(text, left, right) of each time tick label, in CSS px (the axis is drawn on a canvas)."""
    return [(t["text"], t["x"] - t["w"] / 2, t["x"] + t["w"] / 2) for t in v.js("gcodeplanView.ticks()")]


@pytest.mark.parametrize("span", [0.08, 0.004, 3e-5])
def test_time_tick_labels_never_overlap_and_differ(browser, pages, span):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    v.js("([a, b]) => gcodeplanView.zoomTo(a, b)", [1000.0, 1000.0 + span])
    ticks = _tick_labels(v)
    assert len(ticks) >= 3
    texts = [t for t, _, _ in ticks]
    assert len(set(texts)) == len(texts), texts        # enough decimals to tell the ticks apart
    for (_, _, right), (_, left, _) in zip(ticks, ticks[1:]):
        assert left > right, ticks                       # no two labels overlap
    v.page.close()


def test_legend_lists_each_quantity_once(browser, pages):
    html, _, _ = pages("cube", CUBE)
    v = open_page(browser, html)
    shown = v.js("[...document.querySelectorAll('#gpv-timeline .u-legend .u-series')]"
                 ".filter(r => getComputedStyle(r).display !== 'none').map(r => r.textContent.trim())")
    assert len(shown) == 3 and not any("(min)" in s for s in shown), shown
    v.page.close()


def test_page_and_pngs_share_the_feature_colours(browser, pages):
    from matplotlib.colors import to_hex

    from gcodeplan.commands.plot import load_layer_times
    from gcodeplan.report import plots

    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    page = v.js("(() => { const el = document.getElementById('gpv-barinfo');"
                " return [...el.querySelectorAll('.gpv-sw')].map(s => [s.nextSibling.textContent, s.style.background]); })()")
    v.page.close()

    def rgb(css):
        import re

        r, g, b = (int(x) for x in re.findall(r"\d+", css)[:3])
        return f"#{r:02x}{g:02x}{b:02x}"

    page_colors = {name.strip(): rgb(c) for name, c in page}
    times, reader = load_layer_times(str(CUBE), gp.load_machine("klipper"))
    fig = plots.plot_layers(times, list(reader.features), list(reader.layer_z))
    png_colors = {}
    for cont in fig.axes[0].containers:
        png_colors[cont.get_label()] = to_hex(cont.patches[0].get_facecolor())
    common = set(page_colors) & set(png_colors)
    assert len(common) >= 5, (page_colors, png_colors)
    assert {k: page_colors[k] for k in common} == {k: png_colors[k] for k in common}


def test_toolpath_colour_scale_spans_the_layers_speeds(browser, pages):
    html, _, plan = pages("cube", CUBE)
    v = open_page(browser, html)
    m, p = plan.moves, plan.plan
    for layer in (0, 10):
        v.js("l => gcodeplanView.showLayer(l)", layer)
        legend = v.page.locator("#gpv-legend").inner_text()
        sel = (m["layer"] == layer) & (m["kind"] == 1) & (np.hypot(m["x1"] - m["x0"], m["y1"] - m["y0"]) > 0)
        lo, hi = float(p["cruise_v"][sel].min()), float(p["cruise_v"][sel].max())
        if hi - lo < 0.05 * hi:
            lo = 0.0
        import re

        nums = [float(x) for x in re.findall(r"\d+(?:\.\d+)?", legend.split("mm/s")[0])]
        tol = 0.51 if hi - lo >= 10 else 0.051           # the legend rounds to 0 or 1 decimals
        assert nums[0] == pytest.approx(lo, abs=tol) and nums[-1] == pytest.approx(hi, abs=tol), legend
    v.page.close()


def _cnc_program(path):
    """Two pockets at two depths, with rapids between (a CNC program: no extrusion, no layers)."""
    lines = ["G21 G90", "G0 Z5", "G0 X0 Y0"]
    for depth in (-1.0, -2.0):
        lines += [f"G1 Z{depth:.1f} F300", "G1 X20 F1200", "G1 Y20", "G1 X0", "G1 Y0", "G0 Z5"]
    lines += ["M2"]
    path.write_text("\n".join(lines) + "\n")


def test_cnc_program_is_grouped_by_z_level(browser, tmp_path):
    src = tmp_path / "pocket.ngc"
    _cnc_program(src)
    out = tmp_path / "pocket.html"
    assert main(["view", str(src), "-o", str(out), "-q", "--machine", "grbl"]) == 0
    v = open_page(browser, out)
    st = v.js("gcodeplanView.state()")
    assert st["layers"] == [0, 1]
    assert v.page.locator("#gpv-bars-title").inner_text() == "time per Z level, split by feature"
    v.js("gcodeplanView.showLayer(1)")
    assert "(z -2.000 mm)" in v.page.locator("#gpv-layer").inner_text()
    assert st["pathSegments"] >= 4        # the cuts are drawn (not as travel)
    assert "rapids (G0) dashed" in v.page.locator("#gpv-legend").inner_text()
    v.page.close()


def test_linuxcnc_page_draws_the_plans_speed_and_acceleration(browser, tmp_path):
    """The page's inspector tells what plan.sample tells (LinuxCNC rows are not trapezoids)."""
    from gcodeplan.config.linuxcnc import load_linuxcnc_ini

    ini = tmp_path / "mill.ini"
    ini.write_text("[EMCMOT]\nSERVO_PERIOD = 1000000\n[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = mm\n"
                   "MAX_LINEAR_VELOCITY = 100\n[AXIS_X]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                   "[AXIS_Y]\nMAX_VELOCITY = 100\nMAX_ACCELERATION = 1000\n"
                   "[AXIS_Z]\nMAX_VELOCITY = 20\nMAX_ACCELERATION = 500\n")
    src = tmp_path / "zig.ngc"
    pts = "".join(f"G1 X{2.0 * (k + 1):.1f} Y{(k % 2) * 0.5:.1f}\n" for k in range(40))
    src.write_text("G21 G90 G64\nG1 F6000\n" + pts + "M2\n")
    out = tmp_path / "zig.html"
    assert main(["view", str(src), "-o", str(out), "-q", "--linuxcnc-ini", str(ini)]) == 0
    plan = gp.plan(str(src), load_linuxcnc_ini(str(ini)))
    v = open_page(browser, out)
    t = random_inner_times(plan, 30, seed=5)
    _, vel, acc, _ = plan.sample(t)
    speed = np.linalg.norm(vel[:, :3], axis=1)
    got = v.js("ts => ts.map(t => gcodeplanView.inspectAt(t))", t.tolist())
    assert np.max(np.abs(np.array([g["speed"] for g in got]) - speed)) <= 1e-6
    tang = np.einsum("ij,ij->i", vel[:, :3], acc[:, :3]) / np.maximum(speed, 1e-12)
    assert np.max(np.abs(np.array([g["accel"] for g in got]) - tang)) <= 1e-3
    assert np.max(np.abs(tang)) > 100           # the program accelerates: not a step function at 0 mm/s²
    v.page.close()


def test_viewer_sink_keeps_compressed_columns_not_the_plan(tmp_path):
    """The sink compresses as the plan streams in: a 300 000-move program costs a few bytes a move in memory
    (it held ~85 bytes a move before, and a copy more while packing)."""
    import tracemalloc

    from gcodeplan.report.viewer import ViewerSink
    from gcodeplan.schema import MOVE_DTYPE, PLAN_DTYPE

    n_chunk, chunks = 10_000, 30
    sink = ViewerSink()
    rng = np.random.default_rng(1)
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    for k in range(chunks):
        m = np.zeros(n_chunk, MOVE_DTYPE)
        p = np.zeros(n_chunk, PLAN_DTYPE)
        i = np.arange(k * n_chunk, (k + 1) * n_chunk)
        m["x1"] = np.round(rng.uniform(0, 200, n_chunk), 3)
        m["y1"] = np.round(rng.uniform(0, 200, n_chunk), 3)
        m["kind"] = 1
        m["line"] = i + 10
        m["layer"] = i // 5000
        m["feature"] = i % 3
        m["feed_v"] = 50.0
        p["t_start"] = i * 0.05
        p["duration"] = 0.05
        p["start_v"] = p["end_v"] = np.round(rng.uniform(0, 10, n_chunk), 2)
        p["cruise_v"] = 50.0
        p["accel"] = p["decel"] = 1000.0
        sink.add_rows(m, p, k * n_chunk, "trapezoid")
        del m, p
    held = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    assert sink.rows == n_chunk * chunks
    assert held < 12 * sink.rows, f"{held / sink.rows:.1f} bytes a move"


def test_a_big_program_gets_a_bounded_page_of_merged_rows(browser, tmp_path, monkeypatch):
    """Above PAGE_GCODE_BYTES of G-code each page row merges ``thin`` consecutive moves: the page stays about
    that size whatever the file's; the print's time and the layer bars stay exact."""
    import re

    import gcodeplan.report.viewer as viewer

    size = CUBE.stat().st_size
    monkeypatch.setattr(viewer, "PAGE_GCODE_BYTES", (size - 1) // 4)     # just under a quarter: 5 a row
    assert viewer.thin_for(str(CUBE)) == 5
    out = tmp_path / "thin.html"
    assert main(["view", str(CUBE), "-o", str(out), "-q"]) == 0
    full = tmp_path / "full.html"
    monkeypatch.setattr(viewer, "PAGE_GCODE_BYTES", 64 << 20)
    assert main(["view", str(CUBE), "-o", str(full), "-q"]) == 0
    def data_bytes(path):       # the page's data (arrays and G-code text), without the fixed scripts
        text = path.read_text()
        return sum(len(x) for x in re.findall(r'<script type="application/octet-stream" id="gpv-[^"]*"[^>]*>([^<]*)<',
                                               text))

    assert data_bytes(out) < 0.5 * data_bytes(full)
    plan = gp.plan(str(CUBE))
    v = open_page(browser, out)
    st = v.js("gcodeplanView.state()")
    assert st["moves"] == -(-len(plan.moves) // 5)
    assert st["totalTime"] == pytest.approx(plan.total_time_s, abs=1e-9)
    meta = v.js("JSON.parse(document.getElementById('gpv-meta').textContent)")
    bars = dict(zip(meta["layer_bars"]["layers"], (sum(r) for r in meta["layer_bars"]["times"])))
    for layer in (0, 10, 50):
        sel = plan.moves["layer"] == layer
        assert bars[layer] == pytest.approx(float(plan.plan["duration"][sel].sum()), abs=1e-5)
    assert "merges 5 consecutive moves" in v.page.locator("#gpv-sub").inner_text()
    v.page.close()
