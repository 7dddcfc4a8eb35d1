"""A Marlin build's switches that change which G codes exist (a machine's ``marlin_build``; issue 21).

Marlin 2.1's gcode.cpp (``GcodeSuite::process_parsed_command``) dispatches some G codes only when its
Configuration(_adv).h enables a feature, and answers "Unknown command" to them otherwise (off by default, each
one). gcodeplan reads a Marlin line as the default build does (gcode/interp.py PRINTER_CNC_G) unless the
machine's ``marlin_build`` names the switch: then the codes run where gcodeplan already models their meaning
(``MODELLED``), and are refused by name where it does not (``UNMODELLED``): a program's time would be wrong.
"""
from __future__ import annotations

import re

#: switches whose G codes gcodeplan runs as Marlin does: option -> (G codes by whole number, what they do)
MODELLED = {
    # parser.h set_input_linear_units: G20 sets inches (25.4 mm per unit, F and E too), G21 millimetres
    "INCH_MODE_SUPPORT": ((20,), "G20 inch units"),
    # G17-G19 select the plane of G2/G3 (G2_G3.cpp: workspace_plane)
    "CNC_WORKSPACE_PLANES": ((17, 18, 19), "G17-G19 arc planes"),
    # parser.cpp: a line led by X Y Z E F repeats the last G0/G1/G2/G3; G80 cancels that (none at power-up)
    "GCODE_MOTION_MODES": ((80,), "axis-led lines repeat the last G0-G3; G80 cancels"),
}
#: switches whose G codes gcodeplan does not model: option -> (G codes by whole number, why refused)
UNMODELLED = {
    "CNC_COORDINATE_SYSTEMS": ((53, 54, 55, 56, 57, 58, 59),
                               "Marlin's work coordinate systems (G92 sets the active system's offset, G53 runs "
                               "the rest of its line in machine coordinates) are not modelled by gcodeplan"),
    "SAVED_POSITIONS": ((60, 61), "G60/G61 saved positions are not modelled by gcodeplan"),
    "BEZIER_CURVE_SUPPORT": ((5,), "G5 Bézier curves are not modelled by gcodeplan"),
    "G38_PROBE_TARGET": ((38,), "G38 probing moves end at a contact gcodeplan cannot know"),
}
#: every name a ``marlin_build`` may hold
MARLIN_BUILD_OPTIONS = tuple(MODELLED) + tuple(UNMODELLED)


def build_options(text) -> frozenset[str]:
    """The switch names of a ``marlin_build`` value: a string of names separated by blanks or commas (or an
    iterable of names). Raises ValueError naming an unknown one."""
    names = re.split(r"[\s,]+", text.strip()) if isinstance(text, str) else [str(n) for n in text]
    names = [n for n in names if n]
    bad = [n for n in names if n not in MARLIN_BUILD_OPTIONS]
    if bad:
        raise ValueError(f"unknown Marlin build option {bad[0]!r} (known: {', '.join(MARLIN_BUILD_OPTIONS)})")
    return frozenset(names)


def rule_marlin_build(v) -> str | None:
    """Validation rule of the machine field (config/fields.py): None when ``v`` names known switches only."""
    if not isinstance(v, str):
        return "must be a string of Marlin option names separated by blanks or commas"
    try:
        build_options(v)
    except ValueError as err:
        return str(err)
    return None
