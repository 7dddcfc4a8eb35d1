"""Shared test fixtures: where the corpus and the peer reference figures live."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "gcode_samples"
# CI clones the repo with shared/ beside it; a developer checkout has it at ../shared too.
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))
CORPUS = SHARED / "gcode"
REFERENCE = SHARED / "reference"


def shared_path(*parts: str) -> Path:
    """A path under ../shared, skipping the test when it is absent."""
    p = SHARED.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"{p} not available")
    return p


@pytest.fixture
def samples() -> Path:
    return SAMPLES
