"""What the Python interpreter shares: G-code word syntax, command sets, limits on its reports."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..errors import quote




MAX_EVENTS = 200
MAX_WARNINGS = 100

NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
WORD_RE = re.compile(r"\s*([A-Za-z])\s*(" + NUM + r")?")
SEP_OK = re.compile(r"(?:\s|[A-Za-z]|$)")
EXT_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(.*)$", re.S)
KV_RE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(\"[^\"]*\"|'[^']*'|\S*)")
PLACEHOLDER_RE = re.compile(r"\{[^}]*\}?")
CHECKSUM_RE = re.compile(r"\*\s*(\d{1,9})\s*$")   # longer: malformed (int() refuses > 4300 digits)
S3D_LAYER_RE = re.compile(r"\s*layer\s+(-?\d+)(?:\s*,\s*Z\s*=\s*(" + NUM + r"))?", re.I)
HMS_RE = re.compile(r"(?:(\d+)d)?\s*(?:(\d+)h)?\s*(?:(\d+)m)?\s*(?:(\d+)s)?")

# no motion, no effect on the plan: accepted quietly. Coolant M7-M9, PSU M80/M81, motors M17/M18/M84,
# progress M73, heaters and fans M104-M107/M140/M141, reports and messages M105/M110-M119, beeper M300,
# bed levelling state M420, objects M486, motor current M907 (linear advance M900 / M572: _pressure_advance)
QUIET_M = {7, 8, 9, 17, 18, 73, 80, 81, 84, 104, 105, 106, 107, 110, 111, 114, 115, 117, 118, 119, 140, 141,
            300, 420, 486, 907}
# commands whose argument is free text (M23 file name, M117 message...): not tokenised
FREE_TEXT_M = {23, 28, 30, 32, 117, 118, 550, 929}
FREE_TEXT_RE = re.compile(r"[Mm]\s*0*(\d{1,4})(?:\s|$)")
QUIET_G = {40, 94, 98, 99, 17, 18, 19, 20, 21, 49, 80}  # handled below or no effect
# Klipper extended commands with no effect on motion
QUIET_EXT = {"EXCLUDE_OBJECT_START", "EXCLUDE_OBJECT_END", "EXCLUDE_OBJECT_DEFINE", "SET_PRINT_STATS_INFO",
              "M486", "SET_FAN_SPEED", "SET_HEATER_TEMPERATURE", "SET_GCODE_VARIABLE", "RESPOND",
              "SET_RETRACTION", "SET_DISPLAY_TEXT", "SET_LED", "SET_PIN"}
WAIT_M = {109, 190, 191, 116}
M486_RE = re.compile(r"[Mm]\s*0*486(?![0-9.])(.*)$", re.S)
M486_WORD_RE = re.compile(r"\s*([A-Za-z])\s*(\"[^\"]*\"|'[^']*'|[^\s]*)")
OBJECT_COMMENT_RE = re.compile(rb"\s*(stop )?printing object\s*(.*)$", re.S)


def parse_number(text: str, letter: str, interp) -> float:
    """A word's number (finite, else an error naming the word)."""
    v = float(text)
    if not math.isfinite(v):
        interp.error(f"number out of range: {letter}{quote(text)}")
    return v


@dataclass
class Word:
    letter: str        # upper case
    value: float | None
    text: str


