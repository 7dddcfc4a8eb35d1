"""The feature colours the viewer page and the PNG plots share (one palette: a feature has the same colour
in ``gcodeplan view``, in ``gcodeplan report``'s page and in ``gcodeplan plot --what layers``).

Colours follow the feature's index in the reader's feature list (the order the file names them), so that
two pictures of one file agree; the Tableau 10 colours first (matplotlib's ``tab10``), then five more.
"""
from __future__ import annotations

FEATURE_PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7",
                   "#9c755f", "#bab0ac", "#86bcb6", "#d37295", "#8cd17d", "#b6992d", "#499894")
NO_FEATURE_COLOR = "#cccccc"     # moves before the first feature comment
WAITS_COLOR = "#f4cccc"          # heating, homing: time that is not motion
OTHER_COLOR = "#7f7f7f"          # features merged into "other" in a picture with many


def feature_colors(features) -> list[str]:
    """Colour of each feature, by its index in ``features`` (the first name wins when one repeats)."""
    first: dict[str, str] = {}
    out = []
    for k, name in enumerate(features):
        color = first.setdefault(str(name), FEATURE_PALETTE[k % len(FEATURE_PALETTE)])
        out.append(color)
    return out


__all__ = ["FEATURE_PALETTE", "NO_FEATURE_COLOR", "WAITS_COLOR", "OTHER_COLOR", "feature_colors"]
