"""Every example in docs/api.md runs, in order, in one namespace, from the repository's root."""
from __future__ import annotations

import os
import re

from conftest import REPO


def test_every_api_example_runs(capsys):
    text = (REPO / "docs" / "api.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 10
    ns: dict = {}
    old = os.getcwd()
    os.chdir(REPO)
    try:
        for k, code in enumerate(blocks):
            exec(compile(code, f"docs/api.md block {k + 1}", "exec"), ns)
    finally:
        os.chdir(old)
    out = capsys.readouterr().out
    assert "1177.23" in out                 # the estimate example prints Klipper's figure
    assert "4.123583" in out
