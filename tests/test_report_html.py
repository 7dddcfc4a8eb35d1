"""The HTML report: one self-contained page (every image embedded), tables that carry the plan's numbers."""
from __future__ import annotations

import base64
import json
import shutil
import struct
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest

from conftest import shared_path
from gcodeplan.report import html as H
from gcodeplan.commands.report import SlowestLayers, build_report
from gcodeplan.schema import KIND_PRINT, KIND_WAIT, MOVE_DTYPE, PLAN_DTYPE

CUBE = "prusaslicer25_cube20_marlin2.gcode"


class PageParser(HTMLParser):
    """Collects images, headings, table cells and checks that every opened tag of these kinds closes."""

    CHECKED = {"html", "head", "body", "section", "table", "thead", "tbody", "tr", "td", "th", "figure", "h1", "h2",
               "pre", "details", "summary", "figcaption", "title", "style", "caption"}

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.imgs: list[dict] = []
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.text: list[str] = []
        self.h2: list[str] = []
        self._in_h2 = False

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.imgs.append(dict(attrs))
        elif tag in self.CHECKED:
            self.stack.append(tag)
        self._in_h2 = tag == "h2"

    def handle_endtag(self, tag):
        if tag in self.CHECKED:
            if not self.stack or self.stack[-1] != tag:
                self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
            else:
                self.stack.pop()
        if tag == "h2":
            self._in_h2 = False

    def handle_data(self, data):
        self.text.append(data)
        if self._in_h2:
            self.h2.append(data)


def png_size(png: bytes):
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and png[12:16] == b"IHDR"
    return struct.unpack(">II", png[16:24])


@pytest.fixture(scope="module")
def cube_page(request):
    from gcodeplan.config import load_machine

    samples = request.config.rootpath / "gcode_samples"
    return build_report(str(samples / CUBE), load_machine("klipper"), slowest=1)


def test_report_is_one_html_page_with_every_image_embedded(cube_page):
    p = PageParser()
    p.feed(cube_page)
    p.close()
    assert not p.errors and not p.stack, (p.errors, p.stack)
    assert cube_page.startswith("<!DOCTYPE html>")
    # layers + velocity, axes, path of the one slowest layer
    assert len(p.imgs) == 4
    for img in p.imgs:
        src = img["src"]
        assert src.startswith("data:image/png;base64,"), src[:40]
        png = base64.b64decode(src.split(",", 1)[1], validate=True)
        assert png_size(png) == (1600, 900)
        assert img.get("alt")
    # nothing is fetched from elsewhere (the embedded viewer's scripts are inline; a URL in a licence banner is text)
    import re
    assert not re.search(r'<(script|img|link|iframe|source)\b[^>]*\b(src|href)\s*=\s*"(?!data:)', cube_page)
    assert not re.search(r"\b(fetch|XMLHttpRequest|importScripts)\s*\(", cube_page.replace("new Response(", ""))


def test_report_tables_carry_the_plans_numbers(cube_page):
    p = PageParser()
    p.feed(cube_page)
    text = "".join(p.text)
    klipper_total = json.loads(shared_path("reference", "klipper", "times.json").read_text())[CUBE]["total_time_s"]
    assert f"({klipper_total:.1f} s)" in text          # the total, as the reference planner has it
    # the slowest layer drawn is the slowest layer of the table (layer 0 on this cube: first layer, slow speeds)
    slowest_row = text.split("Slowest layers (of 99)")[1]
    assert slowest_row.lstrip().startswith("layerz (mm)time0")
    assert any(h.startswith("Layer 0:") for h in p.h2)


def test_html_helpers_escape_user_text():
    page = H.page("a <b>", H.table(["<th>"], [["<script>alert(1)</script>", 3.5]]))
    p = PageParser()
    p.feed(page)
    assert not p.errors
    assert "<script>" not in page and "&lt;script&gt;" in page
    assert '<td class="num">3.5</td>' in page


def _chunk(layers, kinds, durations):
    m = np.zeros(len(layers), MOVE_DTYPE)
    p = np.zeros(len(layers), PLAN_DTYPE)
    m["layer"], m["kind"], p["duration"] = layers, kinds, durations
    p["t_start"] = np.cumsum(np.r_[0.0, durations[:-1]])
    return m, p


def test_slowest_layers_ranks_runs_across_chunks_and_ignores_waits():
    keep = SlowestLayers(2)
    P, W = KIND_PRINT, KIND_WAIT
    # layer 0: a 500 s heat-up wait + 3 s of motion; layer 1: 4 + 4 s split across two chunks; layer 2: 5 s
    m, p = _chunk([0, 0, 1], [W, P, P], [500.0, 3.0, 4.0])
    keep(m, p, 0)
    m, p = _chunk([1, 2], [P, P], [4.0, 5.0])
    keep(m, p, 3)
    best = keep.finish()
    assert [(r.layer, r.time_s, r.first_index, r.kept) for r in best] == [(1, 8.0, 2, 2), (2, 5.0, 4, 1)]
    # the kept rows keep their real durations (only the ranking leaves waits out)
    assert np.concatenate([q["duration"] for _, q in best[0].parts]).tolist() == [4.0, 4.0]


def test_report_command_writes_the_page_and_reports_user_errors(tmp_path, capsys, request):
    from gcodeplan.cli import main

    src = request.config.rootpath / "gcode_samples" / "b_square.gcode"
    out = tmp_path / "r.html"
    assert main(["report", str(src), "-o", str(out), "--slowest", "1"]) == 0
    page = out.read_text(encoding="utf-8")
    p = PageParser()
    p.feed(page)
    assert not p.errors and len(p.imgs) == 3   # no layers: the whole file is one window
    assert all(i["src"].startswith("data:image/png;base64,") for i in p.imgs)
    capsys.readouterr()
    assert main(["report", str(src), "-o", str(tmp_path / "no" / "r.html")]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert main(["report", str(src), "--slowest", "-1"]) == 2
    assert "--slowest" in capsys.readouterr().err


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome", "headless_shell"):
        path = shutil.which(name)
        if path:
            return path
    return None


def test_report_renders_in_headless_chromium(cube_page, tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("no Chromium installed")
    page = tmp_path / "r.html"
    page.write_text(cube_page, encoding="utf-8")
    shot = tmp_path / "shot.png"
    run = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", f"--screenshot={shot}",
                          "--window-size=1700,2000", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert png_size(shot.read_bytes())[0] == 1700
    dom = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0 and dom.stdout.count("<img") == 4
