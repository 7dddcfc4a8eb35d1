"""RS274NGC program language (O-words, parameters, expressions) as LinuxCNC 2.9 executes it.

A line-level *expander*: it turns program text into the plain lines the interpreter reads, with
parameters and expressions replaced by numbers and the control flow executed, keeping each emitted
line's original source line number (per-line times and errors refer to the file's lines). It runs
only for the ``linuxcnc`` dialect and only from the first line that needs it (an O-word with a
keyword, ``#``, ``[`` outside comments, a ``(DEBUG,`` / ``(PRINT,`` / ``(ABORT,`` comment): plain files
never leave the numba scanner. Rules, from LinuxCNC's ``interp_read.cc`` / ``interp_o_word.cc`` /
``interp_execute.cc`` and its "O Codes" / "Numbered Parameters" documentation (docs/design.md §
"RS274NGC program language"):

* a line is read whole before it runs: every parameter read on a line sees the values from before
  the line, the line's assignments (``#1=…``, any number, the last one of a parameter wins) take
  effect after it;
* expressions ``[…]``: ``**`` over ``* / MOD`` over ``+ -`` over ``EQ NE GT GE LT LE`` over
  ``AND OR XOR``, left to right within a level; a sign binds to the value it precedes (``-2**2`` is 4);
  EQ/NE/LE/GE compare with LinuxCNC's 1e-6 tolerance, GT/LT exactly; MOD's result is never negative;
  trig functions take and give degrees; ``ROUND`` rounds half away from zero, ``FIX`` = floor,
  ``FUP`` = ceil; ``ATAN[y]/[x]``; ``EXISTS[#<name>]``;
* parameters: ``#1``–``#5601`` (``#1``–``#30`` are a subroutine's arguments, restored on return),
  ``#<name>`` local to the subroutine (or the main program) that assigns it, ``#<_name>`` global;
  reading a named parameter never assigned is an error; the interpreter's state (current position
  ``#5420``–``#5428`` / ``#<_x>`` …, work offsets ``#5221``…, modes ``#<_metric>`` …) is read from the
  interpreter through :class:`InterpState`; predefined names it cannot answer are an error, never 0;
* O-words: ``sub``/``endsub``/``return`` (optional ``[value]`` → ``#<_value>``), ``call`` with up to
  30 ``[arguments]`` (a subroutine defined earlier in the file, else ``<name>.ngc`` in the .ini's
  ``[RS274NGC]SUBROUTINE_PATH`` / ``[DISPLAY]PROGRAM_PREFIX``, else a definition later in the same
  file), ``if``/``elseif``/``else``/``endif``, ``while``/``endwhile``, ``do``/``while``,
  ``repeat``/``endrepeat``, ``break``/``continue``; nesting ≤ 10 calls; a loop that repeats more than
  :data:`MAX_LOOP_ITERATIONS` times is an error (a runaway loop, not a hang);
* comments: ``(DEBUG,…)`` and ``(PRINT,…)`` with ``#n`` / ``#<name>`` substituted (``%d``, ``%f``,
  ``%.Nf`` formats) become events, ``(ABORT,…)`` stops with its message; ``(MSG,…)`` goes through to
  the interpreter as before.

Memory: the main program's lines are kept only while a loop in it may jump back (and a subroutine's
body once defined); everything else streams.
"""
from __future__ import annotations

import math
import os
import re

from ..errors import GcodeError

MAX_PARAMETERS = 5602          # LinuxCNC RS274NGC_MAX_PARAMETERS: #1 .. #5601
SUB_PARAMS = 30                # call arguments #1..#30
MAX_CALL_LEVELS = 10           # LinuxCNC INTERP_SUB_ROUTINE_LEVELS
MAX_LOOP_ITERATIONS = 1_000_000
TOLERANCE_EQUAL = 1e-6         # LinuxCNC interp_internal.hh
PERSISTENT = tuple(range(5161, 5170)) + tuple(range(5181, 5190)) + tuple(range(5210, 5391))
READ_ONLY = set(range(5021, 5030)) | set(range(5400, 5414)) | set(range(5420, 5429))
# interpreter-owned numbers: G92 and work offsets (assigning them would bypass the interpreter)
OWNED_WRITE_REFUSED = set(range(5210, 5391))

_KEYWORDS = ("sub", "endsub", "call", "do", "while", "repeat", "if", "elseif", "else", "endif", "break",
             "continue", "endwhile", "endrepeat", "return")          # LinuxCNC's read_o order
_O_HEAD = re.compile(r"\s*(?:/\s*)?(?:[nN]\s*\d[\d\s]*)?[oO]\s*(?:<|\[|#|[\d\s]+[A-Za-z])")
# Fanuc-style subprograms: M98 (call) / M99 (return) first on the line, a bare 'O<number>' starts a body
_M9X_HEAD = re.compile(r"\s*(?:/\s*)?(?:[nN]\s*\d[\d\s]*)?[mM]\s*0*9\s*[89](?![\d.\s]*\d)")
_M9X_NORM = re.compile(r"/?(?:n\d+)?m0*9([89])(?![\d.])")
_BARE_O_NORM = re.compile(r"/?(?:n\d+)?o(\d+)(?:$|[(;])")
_NUM_LITERAL = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)$")
_ACTIVE_COMMENT = re.compile(r"\(\s*(debug|print|abort)\s*,", re.I)
_FMT = re.compile(r"%(d|f|lf|\.(\d)f)")
_BLANKS = re.compile(r"[ \t\r\n]+")
_NUMBER_TEXT = re.compile(r"[+-]*[0-9.]*")


class NgcParams:
    """The parameter table: numbered ``#1``..``#5601``, global named ``#<_name>``, one dict of local named
    parameters per call level. The interpreter owns one per CNC program (gcode/rs274.py): G28/G30 read
    ``#5161``/``#5181``…, G28.1/G30.1, G10 and G92 write them, all in the machine's (user) units as
    LinuxCNC stores them; the values of interpreter-owned numbers (position, tool) come from ``state``
    (:class:`InterpState`) when set.
    """

    def __init__(self, state=None):
        self.numbered = [0.0] * MAX_PARAMETERS
        self.globals: dict[str, float] = {"_value": 0.0, "_value_returned": 0.0}
        self.locals: list[dict[str, float]] = [{}]
        self.state = state
        self.numbered[5220] = 1.0          # G54 selected
        self.numbered[5599] = 1.0          # DEBUG output on

    # ------------------------------------------------------------------ .var file
    def load_var(self, path: str) -> "NgcParams":
        """Read a LinuxCNC parameter file into the table (:func:`read_var`); returns the table
        (``NgcParams().load_var(path).get(5161)``: G28 home X as stored, in the machine's units)."""
        try:
            values = read_var(path)
        except ValueError as err:
            raise GcodeError(str(err), path) from None
        except OSError as err:
            raise GcodeError(f"cannot read parameter file: {err.strerror or err}", path) from None
        return self.update(values)

    def update(self, values: dict[int, float]) -> "NgcParams":
        """Store ``{number: value}`` (a .var file's values) into the numbered parameters; returns the table."""
        for k, v in values.items():
            if 1 <= k < MAX_PARAMETERS:
                self.numbered[k] = float(v)
        return self

    # ------------------------------------------------------------------ access
    def get(self, index: int) -> float:
        """Value of ``#index`` (interpreter-owned numbers asked of ``state`` first)."""
        if self.state is not None and index >= 5000:
            v = self.state.numbered(index)
            if v is not None:
                return v
        return self.numbered[index]

    def set(self, index: int, value: float) -> None:
        """Store ``#index`` (the caller has checked the range and read-only numbers)."""
        self.numbered[index] = value

    def exists(self, name: str) -> bool:
        """``EXISTS[#<name>]``: assigned in the current scope (local) or globally, or predefined."""
        if name.startswith("_"):
            return name in self.globals or (self.state is not None and self.state.knows(name))
        return name in self.locals[-1]

    def get_named(self, name: str) -> float | None:
        """Value of ``#<name>``, None when it does not exist (an error for the caller to word)."""
        if name.startswith("_"):
            if name in self.globals:
                return self.globals[name]
            if self.state is not None:
                return self.state.named(name)
            return None
        return self.locals[-1].get(name)

    def set_named(self, name: str, value: float) -> None:
        """Store ``#<name>``: global when the name starts with ``_``, else local to the current call level."""
        (self.globals if name.startswith("_") else self.locals[-1])[name] = value


def read_var(path: str) -> dict[int, float]:
    """A LinuxCNC parameter (.var) file as ``{number: value}``, values as written (the machine's units):
    ``number value`` per line, other lines passed over as LinuxCNC's restore_parameters does. The one
    reader of the file: the .ini reader checks it with this, the interpreter's table is filled from it.
    Raises OSError when unreadable, ValueError naming the line for a value that is not finite."""
    out: dict[int, float] = {}
    with open(path, "rb") as fh:
        text = fh.read().decode("utf-8", "replace")
    for no, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if len(parts) < 2:
            continue
        try:
            k, v = int(parts[0]), float(parts[1])
        except ValueError:
            continue
        if not 1 <= k < MAX_PARAMETERS:
            continue
        if not math.isfinite(v):
            raise ValueError(f"{path}:{no}: parameter #{k} must be a finite number")
        out[k] = v
    return out


class InterpState:
    """The interpreter's state as LinuxCNC's predefined parameters, in program units (read-only).

    ``numbered(i)`` answers #5021-5029 (machine position), #5083 (tool length offset in force), #5400
    (tool), #5403 (its stored length), #5420-5428 (position in the active coordinate system); the stored
    positions, coordinate systems and G92 offsets are the table's own values; ``named(name)``
    answers ``_x`` …, ``_abs_x`` …, ``_metric`` …; a predefined name it cannot answer raises (never 0).
    """

    _NAMES = {"_x", "_y", "_z", "_a", "_b", "_c", "_u", "_v", "_w", "_abs_x", "_abs_y", "_abs_z", "_abs_a",
              "_abs_b", "_abs_c", "_abs_u", "_abs_v", "_abs_w", "_metric", "_imperial", "_absolute",
              "_incremental", "_inverse_time", "_units_per_minute", "_units_per_rev", "_motion_mode",
              "_plane", "_coord_system", "_ccomp", "_tool_offset", "_retract_r_plane", "_retract_old_z",
              "_ijk_absolute_mode", "_feed", "_current_tool", "_line", "_call_level", "_task", "_vmajor",
              "_vminor", "_lathe_diameter_mode", "_lathe_radius_mode", "_remap_level"}
    _UNSUPPORTED = {"_spindle_on", "_spindle_cw", "_mist", "_flood", "_rpm", "_speed_override",
                    "_feed_override", "_adaptive_feed", "_feed_hold", "_selected_tool", "_selected_pocket",
                    "_current_pocket", "_spindle_rpm_mode", "_spindle_css_mode"}

    def __init__(self, interp, expander=None):
        self.interp = interp
        self.expander = expander

    def knows(self, name: str) -> bool:
        """True for a predefined name (answered, or refused with a message)."""
        return name in self._NAMES or name in self._UNSUPPORTED

    def _pos(self, axis: int, relative: bool) -> float:
        from . import scan as S

        st = self.interp.st
        x = float(st[S.S_X + axis]) - (float(st[S.S_OX + axis]) if relative else 0.0)
        return x / float(st[S.S_UNIT])

    def numbered(self, i: int) -> float | None:
        """The interpreter's value of ``#i``, None when the table's own value applies."""
        it = self.interp
        if 5420 <= i <= 5422:
            return self._pos(i - 5420, True)
        if 5021 <= i <= 5023:
            return self._pos(i - 5021, False)
        if 5423 <= i <= 5428 or 5024 <= i <= 5029:
            return 0.0                                  # A B C U V W are not modelled: they never move
        if i == 5400:
            return float(it.tool)
        if i == 5403:
            # the loaded tool's stored Z offset (user units); the offset in force is #5083
            return float(it.tool_table.get(it.tool, 0.0)) / float(getattr(it, "user_mm", 1.0))
        if i == 5083:
            return float(it.tool_z) / float(getattr(it, "user_mm", 1.0))
        return None                                     # the table's own value (#5161.., #5211.., #5221..)

    def named(self, name: str) -> float | None:
        """The value of the predefined ``#<name>``; None when unknown; raises for a name not modelled."""
        from . import scan as S

        it = self.interp
        axes = "xyzabcuvw"
        if name[1:] in axes and len(name) == 2:
            return self.numbered(5420 + axes.index(name[1]))
        if name.startswith("_abs_") and name[5:] in axes and len(name) == 6:
            return self.numbered(5021 + axes.index(name[5]))
        unit = float(it.st[S.S_UNIT])
        motion = int(it.ist[S.I_MOTION])
        simple = {
            "_metric": 1.0 if unit == 1.0 else 0.0,
            "_imperial": 1.0 if unit != 1.0 else 0.0,
            "_absolute": float(it.ist[S.I_ABS_COORD] != 0),
            "_incremental": float(it.ist[S.I_ABS_COORD] == 0),
            "_inverse_time": 0.0,
            "_units_per_minute": 1.0,
            "_units_per_rev": 0.0,
            "_motion_mode": float(motion * 10 if motion < 100 else motion),   # G38.2 is kept as 382
            "_plane": float(it.plane * 10),
            "_coord_system": (540.0, 550.0, 560.0, 570.0, 580.0, 590.0, 591.0, 592.0, 593.0)[it.work_index],
            "_ccomp": 400.0,
            "_tool_offset": 1.0 if it.tool_z != 0.0 else 0.0,
            "_retract_r_plane": 1.0 if it.retract_mode == 98 else 0.0,
            "_retract_old_z": 1.0 if it.retract_mode == 99 else 0.0,
            "_ijk_absolute_mode": 1.0 if it.arc_abs_centre else 0.0,
            "_feed": float(it.st[S.S_FEED]) * 60.0 / unit,
            "_current_tool": float(it.tool),
            "_line": float(it.line),
            "_task": 1.0,
            "_vmajor": 2.9,
            "_vminor": 0.0,
            "_lathe_diameter_mode": 0.0,
            "_lathe_radius_mode": 0.0,
            "_remap_level": 0.0,
        }
        if name in simple:
            return simple[name]
        if name == "_call_level":
            return float(self.expander.call_level if self.expander is not None else 0)
        if name.startswith(("_hal[", "_ini[")):
            raise _Refused(f"#<{name}>: HAL pins and .ini values are not available to gcodeplan's programs")
        if name in self._UNSUPPORTED:
            raise _Refused(f"#<{name}> is not modelled by gcodeplan (spindle, coolant, overrides and tool "
                           "selection state are not tracked)")
        return None


class _Refused(Exception):
    """A predefined parameter gcodeplan cannot answer (becomes a GcodeError naming the line)."""


def _fmt(v: float) -> str:
    """A number as G-code text that reads back as exactly ``v`` (no exponent: E is a word letter)."""
    r = repr(float(v))
    if "e" in r or "E" in r:
        from decimal import Decimal

        r = format(Decimal(r), "f")
    return r


def close_and_downcase(text: str) -> str:
    """LinuxCNC's line normalisation: blanks removed and letters lower-cased outside comments; a
    ``(`` inside a comment or an unclosed comment is an error (:class:`ValueError` with the message)."""
    if "(" not in text and ";" not in text:
        return _BLANKS.sub("", text).lower()
    out = []
    i = 0
    n = len(text)
    while i < n:
        c = text[i]
        if c == ";":
            out.append(text[i:])
            break
        if c == "(":
            j = text.find(")", i + 1)
            if j < 0:
                raise ValueError("unclosed comment")
            if "(" in text[i + 1:j]:
                raise ValueError("nested comment")
            out.append(text[i:j + 1])
            i = j + 1
            continue
        if c not in " \t\r\n":
            out.append(c.lower() if "A" <= c <= "Z" else c)
        i += 1
    return "".join(out)


def _code_part(text: str) -> str:
    """``text`` without comments (parenthesised and ``;``), for the quick checks."""
    if "(" not in text and ";" not in text:
        return text
    out = []
    depth = False
    for c in text:
        if depth:
            if c == ")":
                depth = False
            continue
        if c == ";":
            break
        if c == "(":
            depth = True
            continue
        out.append(c)
    return "".join(out)


def needs_expansion(text: str) -> bool:
    """True when a line uses the RS274NGC language (an O-word with a keyword, ``#``, ``[`` outside comments,
    an active DEBUG/PRINT/ABORT comment); such a line, and everything after it, goes through
    :class:`Expander`."""
    if "(" in text and _ACTIVE_COMMENT.search(text):
        return True
    code = _code_part(text)
    if "#" in code or "[" in code:
        return True
    return bool(_O_HEAD.match(code) or _M9X_HEAD.match(code))


# ---------------------------------------------------------------------- expressions
class _Reader:
    """LinuxCNC's recursive-descent reading of values on a normalised line (interp_read.cc)."""

    # operator -> precedence (interp_internal.cc precedence())
    _PREC = {"]": 1, "and": 2, "xor": 2, "or": 2, "eq": 3, "ne": 3, "gt": 3, "ge": 3, "lt": 3, "le": 3,
             "+": 4, "-": 4, "*": 5, "/": 5, "mod": 5, "**": 6}
    _OPS = {"a": ("and",), "m": ("mod",), "o": ("or",), "x": ("xor",), "e": ("eq",), "n": ("ne",),
            "g": ("ge", "gt"), "l": ("le", "lt")}
    _UNARY = ("abs", "acos", "asin", "atan", "cos", "exp", "exists", "fix", "fup", "ln", "round", "sin",
              "sqrt", "tan")

    def __init__(self, s: str, params: NgcParams):
        self.s = s
        self.params = params

    def fail(self, msg: str):
        raise _LineError(msg)

    def value(self, i: int) -> tuple[float, int]:
        """read_real_value: number, parameter, [expression], unary function, or a sign before one."""
        s = self.s
        if i >= len(s):
            self.fail("a value is missing at the end of the line")
        c = s[i]
        c1 = s[i + 1] if i + 1 < len(s) else ""
        if c == "[":
            v, i = self.expression(i)
        elif c == "#":
            v, i = self.parameter(i)
        elif c in "+-" and c1 and not c1.isdigit() and c1 != ".":
            v, i = self.value(i + 1)
            if c == "-":
                v = -v
        elif "a" <= c <= "z":
            v, i = self.unary(i)
        else:
            j = _NUMBER_TEXT.match(s, i).end()      # read_real_number: strspn("+-") then strspn("0-9.")
            txt = s[i:j]
            try:
                v = float(txt)
            except ValueError:
                self.fail(f"bad number format {txt or s[i:i + 10]!r}")
            i = j
        if math.isnan(v):
            self.fail("calculation resulted in 'not a number'")
        if math.isinf(v):
            self.fail("calculation resulted in 'infinity'")
        return v, i

    def integer(self, i: int) -> tuple[int, int]:
        """read_integer_value: a value within 0.0001 of an integer."""
        v, i = self.value(i)
        n = math.floor(v)
        if v - n > 0.9999:
            n = math.ceil(v)
        elif v - n > 0.0001:
            self.fail(f"non-integer value {_fmt(v)} where an integer is required")
        return int(n), i

    def name(self, i: int) -> tuple[str, int]:
        j = self.s.find(">", i + 1)
        if j < 0:
            self.fail("named parameter not terminated ('>' missing)")
        return self.s[i + 1:j], j + 1

    def parameter(self, i: int, exists: bool = False) -> tuple[float, int]:
        """read_parameter at ``#``: ``#<name>``, ``#n``, ``##n``, ``#[expr]``."""
        i += 1
        p = self.params
        if i < len(self.s) and self.s[i] == "<":
            name, i = self.name(i)
            if exists:
                return (1.0 if p.exists(name) else 0.0), i
            try:
                v = p.get_named(name)
            except _Refused as err:
                self.fail(str(err))
            if v is None:
                self.fail(f"named parameter #<{name}> not defined")
            return v, i
        k, i = self.integer(i)
        if exists:
            return (1.0 if 1 <= k < MAX_PARAMETERS else 0.0), i
        if not 1 <= k < MAX_PARAMETERS:
            self.fail(f"parameter number #{k} out of range (1..{MAX_PARAMETERS - 1})")
        return p.get(k), i

    def operation(self, i: int) -> tuple[str, int]:
        s = self.s
        if i >= len(s):
            self.fail("unclosed expression (']' missing)")
        c = s[i]
        if c in "+-/]":
            return c, i + 1
        if c == "*":
            if s[i + 1:i + 2] == "*":
                return "**", i + 2
            return "*", i + 1
        for op in self._OPS.get(c, ()):
            if s.startswith(op, i):
                return op, i + len(op)
        self.fail(f"unknown operation {s[i:i + 6]!r} in an expression")

    def expression(self, i: int) -> tuple[float, int]:
        """read_real_expression: LinuxCNC's stack of values and operators, left to right per level."""
        i += 1
        v, i = self.value(i)
        op, i = self.operation(i)
        values = [v]
        ops = [op]
        prec = self._PREC
        while ops[0] != "]":
            v, i = self.value(i)
            op, i = self.operation(i)
            values.append(v)
            ops.append(op)
            # reduce while the newest operator does not bind tighter than the one before it
            while len(ops) > 1 and prec[ops[-1]] <= prec[ops[-2]]:
                right = values.pop()
                newest = ops.pop()
                values[-1] = self.binary(values[-1], ops[-1], right)
                ops[-1] = newest
        return values[0], i

    def binary(self, a: float, op: str, b: float) -> float:
        """execute_binary1/2 (interp_execute.cc)."""
        if op == "+":
            return a + b
        if op == "-":
            return a - b
        if op == "*":
            return a * b
        if op == "/":
            if b == 0.0:
                self.fail("attempt to divide by zero")
            return a / b
        if op == "mod":
            if b == 0.0:
                self.fail("attempt to divide by zero (MOD 0)")
            r = math.fmod(a, b)
            return r + abs(b) if r < 0.0 else r     # always a positive answer
        if op == "**":
            if a < 0.0 and math.floor(b) != b:
                self.fail("attempt to raise a negative number to a non-integer power")
            try:
                return math.pow(a, b)
            except (OverflowError, ValueError):
                self.fail("calculation resulted in 'infinity'")
        if op == "and":
            return 0.0 if (a == 0.0 or b == 0.0) else 1.0
        if op == "or":
            return 1.0 if (a != 0.0 or b != 0.0) else 0.0
        if op == "xor":
            return 1.0 if ((a == 0.0) != (b == 0.0)) else 0.0
        d = abs(a - b)
        if op == "eq":
            return 1.0 if d < TOLERANCE_EQUAL else 0.0
        if op == "ne":
            return 1.0 if d >= TOLERANCE_EQUAL else 0.0
        if op == "le":
            return 1.0 if (d < TOLERANCE_EQUAL or a <= b) else 0.0
        if op == "ge":
            return 1.0 if (d < TOLERANCE_EQUAL or a >= b) else 0.0
        if op == "lt":
            return 1.0 if a < b else 0.0
        if op == "gt":
            return 1.0 if a > b else 0.0
        self.fail(f"unknown operation {op!r}")

    def unary(self, i: int) -> tuple[float, int]:
        s = self.s
        name = None
        for u in self._UNARY:
            if s.startswith(u, i) and s[i + len(u):i + len(u) + 1] == "[":
                name = u
                break
        if name is None:
            m = re.match(r"[a-z]+", s[i:])
            self.fail(f"unknown function {m.group(0) if m else s[i]!r} (or '[' missing after it)")
        i += len(name)
        if name == "exists":
            if s[i + 1:i + 2] != "#":
                self.fail("EXISTS takes one parameter: EXISTS[#<name>]")
            v, i = self.parameter(i + 1, exists=True)
            if s[i:i + 1] != "]":
                self.fail("']' expected after the EXISTS parameter")
            return v, i + 1
        v, i = self.expression(i)
        if name == "atan":
            if s[i:i + 1] != "/":
                self.fail("'/' missing after the first ATAN argument (ATAN[y]/[x])")
            if s[i + 1:i + 2] != "[":
                self.fail("'[' missing after the '/' of ATAN")
            x, i = self.expression(i + 1)
            return math.atan2(v, x) * 180.0 / math.pi, i
        return self.function(name, v), i

    def function(self, name: str, v: float) -> float:
        """execute_unary (interp_execute.cc): angles in degrees."""
        if name == "abs":
            return abs(v)
        if name in ("acos", "asin"):
            if v < -1.0 or v > 1.0:
                self.fail(f"argument to {name.upper()} out of range (-1..1): {_fmt(v)}")
            return (math.acos(v) if name == "acos" else math.asin(v)) * 180.0 / math.pi
        if name == "cos":
            return math.cos(v * math.pi / 180.0)
        if name == "sin":
            return math.sin(v * math.pi / 180.0)
        if name == "tan":
            return math.tan(v * math.pi / 180.0)
        if name == "exp":
            try:
                return math.exp(v)
            except OverflowError:
                self.fail("calculation resulted in 'infinity'")
        if name == "fix":
            return float(math.floor(v))
        if name == "fup":
            return float(math.ceil(v))
        if name == "ln":
            if v <= 0.0:
                self.fail("zero or negative argument to LN")
            return math.log(v)
        if name == "round":
            return float(int(v + (-0.5 if v < 0.0 else 0.5)))
        if name == "sqrt":
            if v < 0.0:
                self.fail("negative argument to SQRT")
            return math.sqrt(v)
        self.fail(f"unknown function {name!r}")


class _LineError(Exception):
    """A reading error on the current line (made into a GcodeError with file and line)."""


def evaluate(expr: str, params: NgcParams | None = None) -> float:
    """The value of one expression or value as LinuxCNC reads it (``"[1 + 2 * 3]"`` → 7.0). For tests and
    tools; raises :class:`ValueError` with LinuxCNC's reason when it cannot."""
    s = close_and_downcase(expr)
    r = _Reader(s, params if params is not None else NgcParams())
    try:
        v, i = r.value(0)
    except _LineError as err:
        raise ValueError(str(err)) from None
    if i != len(s):
        raise ValueError(f"unexpected text after the value: {s[i:]!r}")
    return v


# ---------------------------------------------------------------------- program structure
class _Line:
    __slots__ = ("lineno", "text", "file", "norm")

    def __init__(self, lineno: int, text: str, file: str):
        self.lineno = lineno
        self.text = text
        self.file = file
        self.norm: str | None = None      # close_and_downcase(text), made once (loops run a line again)


class _Sub:
    def __init__(self, name: str, file: str, lineno: int):
        self.name = name
        self.file = file
        self.lineno = lineno
        self.body: list[_Line] = []      # the lines after 'sub', its 'endsub' included
        self.fanuc = False               # an 'O<n>' ... 'M99' subprogram, called by M98


class _Label:
    __slots__ = ("kind", "pc", "lineno", "count", "executed", "iterations")

    def __init__(self, kind: str, pc: int, lineno: int):
        self.kind = kind
        self.pc = pc
        self.lineno = lineno
        self.count = -1          # repeat: remaining iterations, -1 = not started
        self.executed = False    # if: a branch has run
        self.iterations = 0


class _Frame:
    """One execution context: the main program (its lines arrive as the file is read) or a called
    subroutine (its stored body)."""

    def __init__(self, lines: list[_Line], sub: _Sub | None, row_line: int | None):
        self.lines = lines
        self.base = 0                     # index of lines[0] (main program: lines before it were dropped)
        self.pc = 0
        self.sub = sub
        self.row_line = row_line          # main-file line the rows of other files' lines are given
        self.labels: dict[str, _Label] = {}
        self.skipping: str | None = None  # label being skipped to
        self.skip_from = 0                # line where the skipping started
        self.doing_break = False
        self.doing_continue = False
        self.open_loops: dict[str, int] = {}   # label -> pc of loops that may jump back
        self.defining: _Sub | None = None  # main program: the sub whose body is being stored


class _OLine:
    __slots__ = ("name", "kw", "pos", "label")

    def __init__(self, name: str, kw: str, pos: int):
        self.name = name
        self.kw = kw
        self.pos = pos
        self.label = ("o<" + name + ">") if not name.isdigit() and not name.startswith("-") else ("o" + name)


class Expander:
    """RS274NGC expander for one program (module docstring). ``feed(lineno, text)`` takes the file's lines in
    order and yields ``(row_line, text, origin)`` for every line to interpret, in execution order:
    ``row_line`` is the main file's line the line's rows belong to, ``origin`` is None for the main file's
    own lines, else ``(file, line)`` of a subroutine file's line. ``end()`` after the last line checks that
    nothing is left open. Messages go to ``on_event(line, text)``.
    """

    def __init__(self, path: str, params: NgcParams | None = None, subroutine_path=(), on_event=None,
                 max_loop_iterations: int | None = None):
        self.path = path
        self.params = params if params is not None else NgcParams()
        self.subroutine_path = [os.fspath(p) for p in subroutine_path]
        self.on_event = on_event
        self.max_loop_iterations = int(MAX_LOOP_ITERATIONS if max_loop_iterations is None else max_loop_iterations)
        self.subs: dict[str, _Sub] = {}
        self.main = _Frame([], None, None)
        self.stack: list[_Frame] = [self.main]
        self.stopped = False

    # ------------------------------------------------------------------ state
    @property
    def call_level(self) -> int:
        """Subroutine nesting now (``#<_call_level>``): 0 in the main program."""
        return len(self.stack) - 1

    @property
    def busy(self) -> bool:
        """True while the main program cannot run a line as it stands (inside a loop, a sub definition, a
        skipped branch): then every line must come here."""
        f = self.main
        return bool(f.defining is not None or f.skipping is not None or f.open_loops or
                    f.pc - f.base < len(f.lines))

    # ------------------------------------------------------------------ errors
    def _in_sub(self, msg: str) -> str:
        if len(self.stack) > 1 and self.stack[-1].sub is not None:
            msg = f"{msg} (in subroutine {self._label_text(self.stack[-1].sub.name)})"
        return msg

    def _err(self, msg: str, line: _Line, o: _OLine | None = None):
        where = (f"{o.label} {o.kw}".rstrip() + ": ") if o is not None else ""
        raise GcodeError(self._in_sub(where + msg), line.file, line.lineno)

    # ------------------------------------------------------------------ input
    def feed(self, lineno: int, text: str):
        """Take the main file's line ``lineno``; yield what is to run now (class docstring)."""
        if self.stopped:
            return
        self.main.lines.append(_Line(lineno, text, self.path))
        yield from self._run(self.main)
        self._trim()

    def end(self) -> None:
        """After the last line: a sub definition, a skipped block or a loop left open is an error."""
        f = self.main
        if self.stopped:
            return
        if f.defining is not None:
            s = f.defining
            raise GcodeError(f"o{'<' + s.name + '>' if not s.name.isdigit() else s.name} sub: no matching "
                             "endsub before the end of the file", s.file, s.lineno)
        if f.skipping is not None:
            lab = f.labels.get(f.skipping)
            what = lab.kind if lab is not None else "block"
            need = {"if": "endif", "while": "endwhile", "repeat": "endrepeat", "do": "while"}.get(what, "end")
            raise GcodeError(f"{self._label_text(f.skipping)} {what}: no matching {need} before the end of "
                             "the file", self.path, lab.lineno if lab is not None else f.skip_from)
        for name in f.open_loops:
            lab = f.labels[name]
            need = {"while": "endwhile", "repeat": "endrepeat", "do": "while"}[lab.kind]
            raise GcodeError(f"{self._label_text(name)} {lab.kind}: no matching {need} before the end of the "
                             "file", self.path, lab.lineno)

    @staticmethod
    def _label_text(name: str) -> str:
        return "o" + name if name.isdigit() else "o<" + name + ">"

    def _trim(self) -> None:
        f = self.main
        if f.open_loops or f.defining is not None:
            return
        k = f.pc - f.base
        if k > 256 or (k and k == len(f.lines)):
            del f.lines[:k]
            f.base = f.pc

    # ------------------------------------------------------------------ execution
    def _run(self, f: _Frame):
        """Run frame ``f`` from its pc until its lines run out (the main program: until more input comes)."""
        while not self.stopped:
            k = f.pc - f.base
            if k >= len(f.lines):
                return
            line = f.lines[k]
            f.pc += 1
            try:
                yield from self._step(f, line)
            except (_LineError, _Refused) as err:
                raise GcodeError(self._in_sub(str(err)), line.file, line.lineno) from None

    def _o_head(self, s: str, line: _Line, reader: _Reader) -> _OLine | None:
        """The O-word of a normalised line (name, keyword, position after the keyword), or None."""
        i = 0
        if s.startswith("/"):
            i = 1
        if s.startswith("n", i):
            j = i + 1
            while j < len(s) and s[j].isdigit():
                j += 1
            i = j
        if not s.startswith("o", i):
            return None
        i += 1
        if s.startswith("<", i):
            name, i = reader.name(i)
        else:
            n, i = reader.integer(i)
            name = str(n)
        for kw in _KEYWORDS:
            if s.startswith(kw, i):
                return _OLine(name, kw, i + len(kw))
        if i >= len(s) or s[i] in "(;":
            return _OLine(name, "", i)      # a bare O-word: Fanuc-style program number
        raise _LineError(f"unknown command in O-line: {s[i:i + 12]!r}")

    def _step(self, f: _Frame, line: _Line):
        text = line.text
        reader = _Reader("", self.params)
        code = _code_part(text)
        is_o = bool(_O_HEAD.match(code)) if ("o" in code or "O" in code) else False
        if f.defining is not None:
            # storing a sub's body: only its own endsub (and a nested sub, an error) matter
            if is_o:
                s = self._normalise(line)
                reader.s = s
                o = self._o_head(s, line, reader)
                if o is not None and o.kw == "sub":
                    self._err(f"nested subroutine definition inside o{f.defining.name} sub (line "
                              f"{f.defining.lineno})", line, o)
                f.defining.body.append(line)
                if o is not None and o.kw == "endsub" and o.name == f.defining.name:
                    f.defining = None
            else:
                f.defining.body.append(line)
            return
        if not is_o:
            if f.skipping is not None:
                return
            if ("m" in code or "M" in code) and _M9X_HEAD.match(code):
                yield from self._fanuc(f, line)
                return
            yield from self._plain(f, line)
            return
        s = self._normalise(line)
        reader.s = s
        o = self._o_head(s, line, reader)
        if o is None:                    # '(comment) o100 ...': the O-word does not start the line
            if f.skipping is None:
                yield from self._plain(f, line)
            return
        if o.kw == "":
            if f.skipping is None:
                yield self._emit(f, line, line.text)
            return
        key = o.name
        # while skipping, only the label skipped to counts; sub/endsub/call/return names are global in LinuxCNC
        # (never equal to a local if/loop label: 'o1010 return' inside a false 'o1010 if' is skipped)
        if f.skipping is not None and o.kw != "sub" and (o.kw in ("endsub", "call", "return") or key != f.skipping):
            return
        yield from self._control(f, line, o, reader, s)

    def _normalise(self, line: _Line) -> str:
        if line.norm is None:
            try:
                line.norm = close_and_downcase(line.text)
            except ValueError as err:
                raise _LineError(str(err)) from None
        return line.norm

    def _emit(self, f: _Frame, line: _Line, text: str):
        if line.file == self.path:
            return line.lineno, text, None
        return f.row_line, text, (line.file, line.lineno)

    def _rest_only_comments(self, s: str, i: int, line: _Line, o: _OLine) -> None:
        while i < len(s):
            if s[i] == ";":
                return
            if s[i] == "(":
                i = s.index(")", i) + 1
                continue
            self._err(f"unexpected text after the O-word: {s[i:i + 12]!r}" if o is not None else
                      f"unexpected text: {s[i:i + 12]!r}", line, o)

    # ---------------------------------------------------------------- O-words
    def _control(self, f: _Frame, line: _Line, o: _OLine, r: _Reader, s: str):
        """One O-word line, dispatched by its keyword as LinuxCNC's convert_control_functions
        (interp_o_word.cc) does: sub, endsub / return (execute_return), call (execute_call), if, elseif /
        else / endif, do, while, repeat, break / continue, endwhile / endrepeat. A generator: a call runs the
        subroutine's lines."""
        kw = o.kw
        if kw == "sub":
            self._o_sub(f, line, o, s)
            return
        if kw in ("endsub", "return"):
            self._o_return(f, line, o, r, s)
        if kw == "call":
            yield from self._o_call(f, line, o, r, s)
            return
        i = o.pos
        if kw in ("if", "elseif", "while", "repeat"):
            if not s.startswith("[", i):
                self._err(f"'[' missing after '{kw}'", line, o)
            test, i = r.expression(i)
            self._rest_only_comments(s, i, line, o)
        else:
            test = 0.0
            self._rest_only_comments(s, i, line, o)
        handler = _O_HANDLERS.get(kw)
        if handler is None:
            self._err(f"'{kw}' not handled", line, o)
        handler(self, f, line, o, f.labels.get(o.name), test)

    def _o_sub(self, f: _Frame, line: _Line, o: _OLine, s: str) -> None:
        """``o<name> sub``: the definition starts (its lines are read, not run, until its endsub)."""
        if len(self.stack) > 1 or f is not self.main:
            self._err("a subroutine cannot be defined inside a subroutine", line, o)
        if f.skipping is not None:
            return
        old = self.subs.get(o.name)
        if old is not None:
            if old.file == line.file and old.lineno == line.lineno:
                self._err("defined a second time at the same place (LinuxCNC: 'sub found in illegal "
                          "location'): a definition inside a loop, or a sub called before its definition "
                          "and reached afterwards (put it before the call, or after M2)", line, o)
            self._err(f"already defined at {old.file}:{old.lineno}", line, o)
        self._rest_only_comments(s, o.pos, line, o)
        sub = _Sub(o.name, line.file, line.lineno)
        self.subs[o.name] = sub
        f.defining = sub

    def _o_return(self, f: _Frame, line: _Line, o: _OLine, r: _Reader, s: str) -> None:
        """``endsub`` / ``return`` [value] (execute_return): #<_value> and #<_value_returned> are set and the
        frame is left (raises _Return)."""
        value = None
        i = o.pos
        if s.startswith("[", i):
            value, i = r.expression(i)
        self._rest_only_comments(s, i, line, o)
        if f.sub is None:
            self._err("not inside a subroutine", line, o)
        if f.sub.fanuc:
            self._err(f"a Fanuc-style subprogram (O{f.sub.name}, line {f.sub.lineno}) ends with M99", line, o)
        if o.kw == "endsub" and o.name != f.sub.name:
            # ('return' may carry any label: LinuxCNC's own examples use an enclosing if's, o1010 return)
            self._err(f"does not match the subroutine o{f.sub.name} being executed "
                      f"(defined at line {f.sub.lineno})", line, o)
        g = self.params.globals
        g["_value"] = value if value is not None else 0.0
        g["_value_returned"] = 1.0 if value is not None else 0.0
        f.pc = f.base + len(f.lines)          # leave the frame
        raise _Return()

    def _o_call(self, f: _Frame, line: _Line, o: _OLine, r: _Reader, s: str):
        """``o<name> call [a] [b] …`` (execute_call): the arguments, then the subroutine's lines."""
        args = []
        i = o.pos
        while i < len(s) and s[i] in "[(":
            if s[i] == "(":
                i = s.index(")", i) + 1
                continue
            if len(args) >= SUB_PARAMS:
                self._err(f"more than {SUB_PARAMS} arguments", line, o)
            v, i = r.expression(i)
            args.append(v)
        self._rest_only_comments(s, i, line, o)
        yield from self._call(f, line, o, args)

    def _o_if(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``if [test]``: the block runs when the test is non-zero, else it is skipped to its next branch."""
        here = f.pc - 1
        if lab is not None and lab.pc != here:
            self._err(f"duplicate O-word label, already used at line {lab.lineno}", line, o)
        if lab is None:
            lab = f.labels[o.name] = _Label("if", here, line.lineno)
        lab.executed = test != 0.0
        if lab.executed:
            f.skipping = None
        else:
            self._skip(f, o.name, line)

    def _o_elseif(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``elseif [test]`` / ``else`` / ``endif``: the first branch whose test holds runs, once."""
        kw = o.kw
        if lab is None:
            self._err("no matching 'if' (undefined O-word label)", line, o)
        if lab.kind != "if":
            self._err(f"no matching 'if' label (found '{lab.kind}' at line {lab.lineno})", line, o)
        if kw == "endif":
            f.skipping = None
            return
        if lab.executed:
            self._skip(f, o.name, line)
            return
        if kw == "else" or test != 0.0:
            f.skipping = None
            lab.executed = True

    def _o_do(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``do``: a do-while loop opens (its ``while`` decides)."""
        here = f.pc - 1
        f.skipping = None
        if lab is None:
            lab = f.labels[o.name] = _Label("do", here, line.lineno)
        elif lab.pc != here:
            self._err(f"duplicate O-word label, already used at line {lab.lineno}", line, o)
        f.open_loops[o.name] = lab.pc

    def _o_while(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``while [test]``: the end of a do-while loop (back to its ``do`` while the test holds), or a
        while loop's head (its body skipped when the test is zero)."""
        key = o.name
        here = f.pc - 1
        if lab is not None and lab.kind == "do":
            self._check_open(f, key, lab, line, o)
            f.skipping = None
            if test != 0.0 and not f.doing_break:
                self._loop_back(f, lab, line, o)
            else:
                self._loop_done(f, key, lab)
            return
        if lab is not None and lab.pc != here:
            self._err(f"duplicate O-word label, already used at line {lab.lineno}", line, o)
        f.skipping = None
        if lab is None:
            lab = f.labels[key] = _Label("while", here, line.lineno)
        f.open_loops[key] = lab.pc
        if test == 0.0:
            self._skip(f, key, line)

    def _o_repeat(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``repeat [count]``: the body runs count times (the count read once, rounded as LinuxCNC does)."""
        key = o.name
        here = f.pc - 1
        if lab is not None and lab.pc != here:
            self._err(f"duplicate O-word label, already used at line {lab.lineno}", line, o)
        f.skipping = None
        if lab is None:
            lab = f.labels[key] = _Label("repeat", here, line.lineno)
        f.open_loops[key] = lab.pc
        if lab.count == -1:
            lab.count = int(round(test))      # LinuxCNC round_to_int: nearbyint, halves to even
        if lab.count > 0:
            lab.count -= 1
        else:
            lab.count = -1
            self._skip(f, key, line)

    def _o_break(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``break`` / ``continue``: the rest of the loop body is skipped, then the loop ends / goes on."""
        key = o.name
        if lab is None:
            self._err("no matching while/do (undefined O-word label)", line, o)
        if lab.kind not in ("while", "do"):
            self._err(f"no matching while/do label (found '{lab.kind}' at line {lab.lineno})", line, o)
        self._check_open(f, key, lab, line, o)
        if o.kw == "continue" and f.skipping == key:
            return
        self._skip(f, key, line)
        if o.kw == "break":
            f.doing_break = True
        else:
            f.doing_continue = True

    def _o_endwhile(self, f: _Frame, line: _Line, o: _OLine, lab: _Label | None, test: float) -> None:
        """``endwhile`` / ``endrepeat``: back to the loop's head, or out of it after a break."""
        key = o.name
        want = "while" if o.kw == "endwhile" else "repeat"
        if lab is None:
            self._err(f"no matching '{want}' (undefined O-word label)", line, o)
        if lab.kind != want:
            self._err(f"no matching '{want}' label (found '{lab.kind}' at line {lab.lineno})", line, o)
        self._check_open(f, key, lab, line, o)
        if f.skipping == key:
            f.skipping = None
            if f.doing_continue:
                f.doing_continue = False
                self._loop_back(f, lab, line, o)
            else:
                f.doing_break = False
                if lab.kind == "repeat":
                    lab.count = -1
                self._loop_done(f, key, lab)
            return
        self._loop_back(f, lab, line, o)

    def _check_open(self, f: _Frame, key: str, lab: _Label, line: _Line, o: _OLine) -> None:
        if key not in f.open_loops:
            self._err(f"outside its loop: the {lab.kind} at line {lab.lineno} has already ended", line, o)

    def _skip(self, f: _Frame, key: str, line: _Line) -> None:
        f.skipping = key
        f.skip_from = line.lineno

    def _loop_back(self, f: _Frame, lab: _Label, line: _Line, o: _OLine) -> None:
        lab.iterations += 1
        if lab.iterations > self.max_loop_iterations:
            self._err(f"loop from line {lab.lineno} repeated more than {self.max_loop_iterations} times "
                      "(a runaway loop?)", line, o)
        f.doing_continue = False
        f.pc = lab.pc

    def _loop_done(self, f: _Frame, key: str, lab: _Label) -> None:
        f.doing_break = False
        f.doing_continue = False
        lab.iterations = 0
        f.open_loops.pop(key, None)

    # ---------------------------------------------------------------- calls
    def _call(self, f: _Frame, line: _Line, o: _OLine, args: list[float] | None, sub: _Sub | None = None):
        """Run a subroutine (``args`` None: a Fanuc M98 call, #1..#30 shared with the caller)."""
        if sub is None:
            sub = self.subs.get(o.name)
            if sub is None:
                sub = self._find_sub(o.name, line, o)
            if sub.fanuc:
                self._err(f"O{sub.name} (line {sub.lineno}) is a Fanuc-style subprogram: call it with M98 P{sub.name}",
                          line, o)
        if len(self.stack) > MAX_CALL_LEVELS - 1:
            self._err(f"too many nested subroutine calls (at most {MAX_CALL_LEVELS - 1})", line, o)
        p = self.params
        saved = p.numbered[1:SUB_PARAMS + 1]
        if args is not None:
            p.numbered[1:SUB_PARAMS + 1] = args + [0.0] * (SUB_PARAMS - len(args))
        p.globals["_value"] = 0.0
        p.globals["_value_returned"] = 0.0
        p.locals.append({})
        row = f.row_line if line.file != self.path else line.lineno
        frame = _Frame(sub.body, sub, row)
        self.stack.append(frame)
        try:
            yield from self._run(frame)
            # the body ends with its endsub, which raises _Return: arriving here means it was skipped over
            last = sub.body[-1] if sub.body else line
            if frame.skipping is not None:
                lab = frame.labels.get(frame.skipping)
                kind = lab.kind if lab is not None else "block"
                raise GcodeError(f"{self._label_text(frame.skipping)} {kind}: no matching end before the "
                                 f"subroutine's endsub", last.file, lab.lineno if lab is not None else last.lineno)
        except _Return:
            pass
        finally:
            self.stack.pop()
            p.locals.pop()
            if args is not None:
                p.numbered[1:SUB_PARAMS + 1] = saved

    def _fanuc(self, f: _Frame, line: _Line):
        """LinuxCNC's Fanuc-style subprograms: ``M98 P<n> [L<count>]`` runs the ``O<n>`` ... ``M99`` block that
        follows later in the file (#1..#30 shared, L0 = not at all); ``M99`` returns from it."""
        s = self._normalise(line)
        m = _M9X_NORM.match(s)
        if m is None:
            yield from self._plain(f, line)
            return
        r = _Reader(s, self.params)
        if m.group(1) == "9":
            if f.sub is None:
                raise _LineError("M99 in the main program: LinuxCNC restarts the program from its first line "
                                 "(an endless program), which cannot be timed")
            if not f.sub.fanuc:
                raise _LineError(f"M99 inside o{f.sub.name} sub: an 'O... sub' ends with 'O... endsub'")
            self._rest_only_comments(s, m.end(), line, None)
            f.pc = f.base + len(f.lines)
            raise _Return()
        words: dict[str, float] = {}
        i = m.end()
        while i < len(s):
            c = s[i]
            if c == "(":
                i = s.index(")", i) + 1
            elif c == ";":
                break
            elif c in "pl":
                if c in words:
                    raise _LineError(f"M98: {c.upper()} given twice")
                words[c], i = r.value(i + 1)
            else:
                raise _LineError(f"M98 takes P (subprogram number) and L (repeat count), not {c.upper()!r}")
        if "p" not in words:
            raise _LineError("M98 needs P, the subprogram number")
        r.s = _fmt(words["p"])
        n, _ = r.integer(0)
        count = int(round(words.get("l", 1.0)))       # round_to_int: nearbyint, halves to even
        name = str(n)
        o = _OLine(name, "", 0)
        o.label = f"M98 P{name}"
        sub = self.subs.get(name)
        if sub is None and count > 0:
            sub = self._scan_for_fanuc(name, line)
            if sub is None:
                self._err(f"no subprogram O{name} after this line (LinuxCNC looks for 'O{name}' ... 'M99' "
                          "later in the file)", line, o)
            self.subs[name] = sub
        if sub is not None and not sub.fanuc:
            self._err(f"o{name} (line {sub.lineno}) is an 'O... sub' subroutine: call it with o{name} call", line, o)
        for _ in range(count):
            yield from self._call(f, line, o, None, sub)

    def _scan_for_fanuc(self, name: str, line: _Line) -> _Sub | None:
        """The ``O<name>`` ... ``M99`` block after ``line`` in the main file (LinuxCNC's forward seek)."""
        if line.file != self.path or not os.path.isfile(self.path):
            return None
        try:
            with open(self.path, "rb") as fh:
                text = fh.read().decode("utf-8", "replace")
        except OSError as err:
            raise GcodeError(f"cannot read: {err.strerror or err}", self.path) from None
        sub = None
        for no, raw in enumerate(text.split("\n"), 1):
            if no <= line.lineno:
                continue
            raw = raw.rstrip("\r")
            try:
                s = close_and_downcase(raw)
            except ValueError:
                s = ""
            if sub is None:
                m = _BARE_O_NORM.match(s)
                if m and str(int(m.group(1))) == name:
                    sub = _Sub(name, self.path, no)
                    sub.fanuc = True
                continue
            sub.body.append(_Line(no, raw, self.path))
            m = _M9X_NORM.match(s)
            if m and m.group(1) == "9":
                return sub
        if sub is not None:
            raise GcodeError(f"O{name}: no M99 before the end of the file", self.path, sub.lineno)
        return None

    def _find_sub(self, name: str, line: _Line, o: _OLine) -> _Sub:
        """A sub not defined yet: ``<name>.ngc`` in the subroutine path, else later in the main file."""
        fname = name + ".ngc"
        for d in self.subroutine_path:
            path = os.path.join(d, fname)
            if os.path.isfile(path):
                return self._load_file_sub(name, path, line, o)
        if os.path.isfile(self.path):
            sub = self._scan_for_sub(name, self.path, after=line.lineno if line.file == self.path else 0)
            if sub is not None:
                self.subs[name] = sub
                return sub
        fanuc = self._scan_for_fanuc(name, line)
        if fanuc is not None:
            self._err(f"O{name} (line {fanuc.lineno}) is a Fanuc-style subprogram: call it with M98 P{name}",
                      line, o)
        where = ", ".join(self.subroutine_path) or "none: no [RS274NGC]SUBROUTINE_PATH"
        self._err(f"unknown subroutine: not defined in this file and no file {fname} in the subroutine "
                  f"path ({where})", line, o)

    def _load_file_sub(self, name: str, path: str, line: _Line, o: _OLine) -> _Sub:
        sub = self._scan_for_sub(name, path, after=0)
        if sub is None:
            self._err(f"{path} has no 'o<{name}> sub' ... 'endsub'", line, o)
        self.subs[name] = sub
        return sub

    def _scan_for_sub(self, name: str, path: str, after: int) -> _Sub | None:
        """Read ``path`` for the definition of sub ``name`` (on a line after ``after``)."""
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError as err:
            raise GcodeError(f"cannot read subroutine file: {err.strerror or err}", path) from None
        text = data.decode("utf-8", "replace")
        if text.startswith("\ufeff"):
            text = text[1:]
        lines = text.split("\n")
        sub = None
        r = _Reader("", self.params)
        for no, raw in enumerate(lines, 1):
            raw = raw.rstrip("\r")
            if no <= after and sub is None:
                continue
            code = _code_part(raw)
            o = None
            if _O_HEAD.match(code):
                try:
                    r.s = close_and_downcase(raw)
                    o = self._o_head(r.s, _Line(no, raw, path), r)
                except (_LineError, ValueError) as err:
                    raise GcodeError(str(err), path, no) from None
            if sub is None:
                if o is not None and o.kw == "sub" and o.name == name:
                    sub = _Sub(name, path, no)
                continue
            sub.body.append(_Line(no, raw, path))
            if o is not None and o.kw == "sub":
                raise GcodeError(f"nested subroutine definition inside o<{name}> sub (line {sub.lineno})", path, no)
            if o is not None and o.kw == "endsub" and o.name == name:
                return sub
        if sub is not None:
            raise GcodeError(f"o<{name}> sub: no matching endsub before the end of the file", path, sub.lineno)
        return None

    # ---------------------------------------------------------------- plain lines
    def _plain(self, f: _Frame, line: _Line):
        """A line that is not an O-word: parameters and expressions substituted, assignments made after the
        line is read, active comments reported; yields the line to interpret."""
        text = line.text
        code = _code_part(text)
        active = "(" in text and _ACTIVE_COMMENT.search(text)
        if "#" not in code and "[" not in code and not active:
            yield self._emit(f, line, text)
            return
        s = self._normalise(line)
        r = _Reader(s, self.params)
        out: list[str] = []
        sets: list[tuple[str | int, float]] = []
        last_comment = None
        i = 0
        n = len(s)
        if s.startswith("/"):
            out.append("/")
            i = 1
        while i < n:
            c = s[i]
            if c == "(":
                j = s.index(")", i)
                last_comment = s[i + 1:j]
                out.append(s[i:j + 1])
                i = j + 1
            elif c == ";":
                out.append(s[i:])
                break
            elif c == "#":
                i += 1
                if s.startswith("<", i):
                    name, i = r.name(i)
                    target: str | int = name
                    if name in self.params.globals and name in ("_value", "_value_returned") or \
                            (self.params.state is not None and self.params.state.knows(name)):
                        raise _LineError(f"#<{name}> is read-only")
                else:
                    k, i = r.integer(i)
                    if not 1 <= k < MAX_PARAMETERS:
                        raise _LineError(f"parameter number #{k} out of range (1..{MAX_PARAMETERS - 1})")
                    if k in READ_ONLY:
                        raise _LineError(f"parameter #{k} is read-only")
                    if k in OWNED_WRITE_REFUSED:
                        raise _LineError(f"assigning #{k} (G92 / coordinate system offsets) is not supported "
                                         "by gcodeplan: use G10 L2 / G92")
                    target = k
                if not s.startswith("=", i):
                    raise _LineError("'=' missing in a parameter setting")
                v, i = r.value(i + 1)
                sets.append((target, v))
            elif "a" <= c <= "z":
                if c == "o":
                    raise _LineError("an O-word must start the line")
                j0 = i + 1
                v, i = r.value(j0)
                lit = s[j0:i]
                out.append(c.upper() + (lit if _NUM_LITERAL.match(lit) else _fmt(v)))
            else:
                raise _LineError(f"bad character {c!r} used")
        for target, v in sets:
            if isinstance(target, int):
                self.params.set(target, v)
            else:
                self.params.set_named(target, v)
        if last_comment is not None:
            self._active_comment(last_comment, line, f)
        yield self._emit(f, line, " ".join(out))

    def _active_comment(self, body: str, line: _Line, f: _Frame) -> None:
        """(DEBUG,…) / (PRINT,…) as events with parameters substituted; (ABORT,…) stops (convert_comment)."""
        lc = body.lstrip().lower()
        for kind in ("debug,", "print,", "abort,"):
            if lc.startswith(kind):
                rest = body.lstrip()[len(kind):]
                msg = self._substitute_comment(rest)
                if kind == "abort,":
                    raise _LineError(f"(ABORT,{msg})")
                if kind == "debug," and not self.params.numbered[5599] > 0.0:
                    return
                if self.on_event is not None:
                    row = line.lineno if line.file == self.path else f.row_line
                    self.on_event(row, f"{kind[:-1].upper()} {msg.strip()}")
                return

    def _substitute_comment(self, text: str) -> str:
        """convert_param_comment: ``#n`` / ``#<name>`` replaced by their values (``%lf`` unless a ``%d``,
        ``%f`` or ``%.Nf`` before them says otherwise); an unknown named parameter prints ``######``."""
        out = []
        fmt = "%lf"
        i = 0
        n = len(text)
        while i < n:
            m = _FMT.match(text, i)
            if m:
                fmt = m.group(0)
                i = m.end()
                continue
            c = text[i]
            if c != "#":
                out.append(c)
                i += 1
                continue
            if text.startswith("<", i + 1):
                j = text.find(">", i + 2)
                if j < 0:
                    out.append(c)
                    i += 1
                    continue
                name = re.sub(r"\s", "", text[i + 2:j]).lower()
                try:
                    v = self.params.get_named(name)
                except _Refused:
                    v = None
                i = j + 1
            else:
                m2 = re.match(r"\d+", text[i + 1:])
                if not m2:
                    out.append(c)
                    i += 1
                    continue
                k = int(m2.group(0))
                v = self.params.get(k) if 1 <= k < MAX_PARAMETERS else None
                i += 1 + len(m2.group(0))
            if v is None:
                out.append("######")
            elif fmt == "%d":
                out.append(str(int(round(v))))
            elif fmt == "%f":
                out.append(f"{v:.4f}")
            elif fmt == "%lf":
                out.append(f"{v:.6f}")
            else:
                out.append(f"{v:.{int(fmt[2])}f}")
        return "".join(out)


class _Return(Exception):
    """endsub / return: leave the current frame."""


# the O-word keywords that take a test (or none) and their handlers: convert_control_functions' cases
_O_HANDLERS = {"if": Expander._o_if, "elseif": Expander._o_elseif, "else": Expander._o_elseif,
               "endif": Expander._o_elseif, "do": Expander._o_do, "while": Expander._o_while,
               "repeat": Expander._o_repeat, "break": Expander._o_break, "continue": Expander._o_break,
               "endwhile": Expander._o_endwhile, "endrepeat": Expander._o_endwhile}


# ---------------------------------------------------------------------- the interpreter's hook
def expand_line(interp, text: str, lineno: int) -> None:
    """Run the main file's line ``lineno`` through the interpreter's :class:`Expander` (made on first use)
    and interpret what it emits; lines keep their own numbers. Called by ``Interpreter.handle`` for the
    linuxcnc dialect when :func:`needs_expansion` says so or the expander is already busy."""
    from . import scan as S

    ex = interp.ngc
    if ex is None:
        # the interpreter's own table (gcode/rs274.py: the .var values, G28.1, G10, G92 write into it)
        params = getattr(interp, "params", None)
        if params is None:
            params = NgcParams()
        settings = getattr(interp.machine, "linuxcnc", None)
        def on_event(row: int, msg: str) -> None:
            interp.line = row
            interp.event(msg)

        ex = Expander(interp.path, params, getattr(settings, "subroutine_path", ()) or (), on_event)
        params.state = InterpState(interp, ex)
        interp.ngc = ex
    ist = interp.ist
    for row, line_text, origin in ex.feed(lineno, text):
        interp.line = row
        try:
            interp._handle_text(line_text.encode("utf-8", "surrogateescape"), line_text.strip())
        except GcodeError as err:
            if origin is not None and err.file == interp.path:
                raise GcodeError(f"{err.message} (subroutine file line, called from {interp.path}:{row})",
                                 origin[0], origin[1]) from None
            raise
        if ist[S.I_STOPPED]:
            ex.stopped = True
            break
    interp.line = lineno
    busy = ex.busy and not ex.stopped
    if busy:
        ist[S.I_TO_PYTHON] = 1
        interp._ngc_forced = True
    elif getattr(interp, "_ngc_forced", False):
        ist[S.I_TO_PYTHON] = 0
        interp._ngc_forced = False


def subroutine_dirs(ini_path: str, subroutine_path: str | None, program_prefix: str | None) -> list[str]:
    """LinuxCNC's search directories for ``o<name> call`` files: ``[DISPLAY]PROGRAM_PREFIX`` then the
    ``:``-separated ``[RS274NGC]SUBROUTINE_PATH``, relative paths from the .ini's directory."""
    base = os.path.dirname(os.path.abspath(ini_path))
    out = []
    for raw in ([program_prefix] if program_prefix else []) + (subroutine_path.split(":") if subroutine_path else []):
        raw = os.path.expanduser(raw.strip())
        if raw:
            out.append(raw if os.path.isabs(raw) else os.path.normpath(os.path.join(base, raw)))
    return out


__all__ = ["NgcParams", "InterpState", "read_var", "Expander", "evaluate", "needs_expansion", "expand_line",
           "close_and_downcase", "subroutine_dirs", "MAX_LOOP_ITERATIONS"]
