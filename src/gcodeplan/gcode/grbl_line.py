"""A program line as grbl 1.1 reads it before it parses any word: its serial line filter and its word lexer.

grbl keeps a line in an 80-byte buffer (protocol.c ``protocol_main_loop``): it drops blanks and control
characters (every byte up to the space), ``/`` (block delete is not supported), ``(...)`` comments (to the ``)``
or the line's end) and everything after a ``;``, turns ``a``-``z`` into capitals, and keeps at most 79 bytes (the
80th is the terminating NUL): a longer line is not parsed at all, grbl answers ``error:11`` (line overflow).
``gc_execute_line`` (gcode.c, step 2) then reads the kept bytes as words, a letter ``A``-``Z`` and a number read
by ``read_float`` (nuts_bolts.c: an optional sign, digits with at most one ``.``, no exponent): a word that does
not start with a letter is ``error:1`` (expected command letter), a letter without a number ``error:2`` (bad
number format). So grbl reads ``G1 X10 20`` as ``G1X1020`` (X1020), ``G1 X1.2.3`` fails at the second ``.``
(error:1), ``G1 X-`` at the missing digits (error:2), a checksum ``*71`` at the ``*`` (error:1). (A line that
is only ``%`` keeps the interpreter's program start / end reading: grbl answers it error:1 and does nothing.)

These functions only say what grbl keeps and where its lexer stops; the interpreter
(:meth:`.rs274.Rs274Commands.grbl_line`) checks the words and runs the line.
"""
from __future__ import annotations

import math
import re

from .lexing import Word
from .rs274 import GRBL_LINE_BUFFER_SIZE, GRBL_MAX_LINE_NUMBER, grbl_word_error
from .scan import S_UNIT

# a comment as protocol.c drops it: "(" to the next ")" (or the line's end), ";" to the line's end; the
# leftmost match wins, so a ";" inside parentheses and a ")" after a ";" stay inside their comment
_COMMENT = re.compile(rb"\([^)]*\)?|;.*", re.S)
# the bytes protocol.c throws away outside comments: blanks and control characters (<= space) and "/"
_DROPPED = re.compile(rb"[\x00-\x20/]+")
# read_float's number: an optional sign, then digits with at most one "." (no digits at all: not a number)
_NUMBER = re.compile(rb"[-+]?[0-9]*(?:\.[0-9]*)?")
# two pieces of a number apart in the text that grbl joins into one (blanks or "/" between them; a comment
# between them is a blank in ``spaced``)
_JOINED = re.compile(rb"[0-9.][\x00-\x20/]+[0-9.]")


def _blank_for_comment(m: re.Match) -> bytes:
    return b" " if m.group(0)[:1] == b"(" else b""


def protocol_line(raw: bytes) -> tuple[bytes, bytes, bool]:
    """protocol.c's filter of one line ``raw`` (its bytes, no newline): ``(kept, spaced, overflow)``: the bytes
    grbl keeps (capitals, no blanks or comments), the line before blanks are dropped (a ``(...)`` comment left
    as a blank, for :func:`joins_numbers` and messages), and whether the line overflows grbl's buffer (more
    than 79 bytes kept: error:11)."""
    spaced = _COMMENT.sub(_blank_for_comment, raw)
    kept = _DROPPED.sub(b"", spaced).upper()
    return kept, spaced, len(kept) > GRBL_LINE_BUFFER_SIZE - 1


def lex(kept: bytes) -> tuple[list[tuple[str, str]], int, str]:
    """gc_execute_line's reading of the words of ``kept`` (:func:`protocol_line`): ``(words, error, what)``,
    words the ``(letter, number text)`` pairs read before the first word grbl cannot read, error 0 when there
    is none, else 1 (no letter where a word starts) or 2 (a letter without a number), ``what`` naming it."""
    words: list[tuple[str, str]] = []
    pos, n = 0, len(kept)
    while pos < n:
        letter = kept[pos:pos + 1]
        if not b"A" <= letter <= b"Z":
            return words, 1, f"{kept[pos:pos + 12].decode('latin-1')!r} (a word must start with a letter)"
        m = _NUMBER.match(kept, pos + 1)
        text = m.group(0)
        if not any(48 <= c <= 57 for c in text):
            return words, 2, f"word {letter.decode()} without a number in {kept[pos:pos + 40].decode('latin-1')}"
        words.append((letter.decode(), text.decode()))
        pos = m.end()
    return words, 0, ""


def joins_numbers(spaced: bytes) -> bool:
    """True when grbl, dropping blanks and comments, joins two pieces of a number of ``spaced``
    (:func:`protocol_line`) into one: ``X10 20`` is X1020 on grbl, two words or an error anywhere else."""
    return _JOINED.search(spaced) is not None


# grbl settings ($N=value, settings.c) that change a program's time: $1 step idle delay (a wait at each stop),
# $11 junction deviation, $12 arc tolerance, $32 laser mode (no stop at S changes), $100-$102 steps/mm,
# $110-$112 max rates, $120-$122 accelerations
TIMING_SETTINGS = frozenset((1, 11, 12, 32, 100, 101, 102, 110, 111, 112, 120, 121, 122))
# the other settings grbl 1.1 has (report/motion polarity, limits, homing, travel, the spindle's rpm range): no
# effect on the time
OTHER_SETTINGS = frozenset((0, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 24, 25, 26, 27, 30, 31, 130, 131, 132))
# the settings a program's line changes from there on (LIMITS columns; mm/min → mm/s for the rates)
LIMITS_SETTINGS = {11: ("junction_dev", 1.0), 110: ("axis_v_x", 1 / 60), 111: ("axis_v_y", 1 / 60),
                   112: ("axis_v_z", 1 / 60), 120: ("axis_a_x", 1.0), 121: ("axis_a_y", 1.0), 122: ("axis_a_z", 1.0)}
# system commands that neither move nor change a setting (system.c): help, settings / parameters / modes /
# build info / startup lines reports, alarm unlock
REPORT_COMMANDS = frozenset((b"$", b"$$", b"$#", b"$G", b"$I", b"$N", b"$X"))
_SETTING = re.compile(rb"\$([0-9]+(?:\.[0-9]*)?)=([-+]?[0-9]*\.?[0-9]*)")
_JOG_G = (20.0, 21.0, 90.0, 91.0, 53.0)     # gcode.c: a jog takes units, distance mode and G53 only


class GrblLines:
    """Mixed into :class:`.interp.Interpreter`: a grbl line as grbl reads it, before its words run."""

    def grbl_line(self, raw: bytes) -> str | None:
        """The text of the grbl line ``raw`` (its bytes, no newline) for the rest of the interpreter: the words
        grbl reads, blank-separated (``G1 X1020`` for ``G1 X10 20``, with a warning); None when there is
        nothing more to do: an empty line, a ``$`` system line (:meth:`_grbl_system_line`), or a line grbl
        answers with an error before it checks the words (error:11 overflow, error:1 / 2 unreadable word,
        or the first word's error before an unreadable one), each warned about once (an error under
        ``--strict``) and otherwise skipped as grbl skips it."""
        if raw.startswith(b"\xef\xbb\xbf"):
            raw = raw[3:]                # a UTF-8 byte order mark: a sender does not send it
        kept, spaced, overflow = protocol_line(raw)
        self._grbl_route()          # (the machine's start wait hands the first line here and resets the route)
        self.grbl_words = None
        self.grbl_line_number = None
        if overflow:
            self.grbl_reject(11, f"{len(kept)} characters without blanks and comments (grbl's line buffer "
                                 f"holds {GRBL_LINE_BUFFER_SIZE - 1})")
            return None
        if not kept:
            return None
        if kept[:1] == b"$":
            self._grbl_system_line(kept)
            return None
        pairs, lex_error, what = lex(kept)
        words = [Word(k, float(t), t) for k, t in pairs]
        first, _ = grbl_word_error(words)
        if first is None and lex_error:
            first = (lex_error, what, ())
        n = next((int(w.value) for w in words if w.letter == "N"), None)
        if first is None and all(w.letter == "N" for w in words) and n > GRBL_MAX_LINE_NUMBER:
            first = (27, f"N{n} (line numbers up to {GRBL_MAX_LINE_NUMBER})", ())
        if first is not None:
            self.grbl_reject(*first)
            return None
        self.grbl_words = words
        self.grbl_line_number = n
        text = " ".join(k + (str(int(float(t))) if k == "N" else t) for k, t in pairs)
        if joins_numbers(spaced):
            self.warn(f"{spaced.decode('latin-1').strip()[:40]}: grbl drops blanks and reads {text[:40]}")
        return text

    # ------------------------------------------------------------------ $ lines
    def _grbl_system_line(self, kept: bytes) -> None:
        """A ``$`` line of a program (system.c system_execute_line): ``$J=`` jogs (:meth:`_grbl_jog`); a setting
        ``$N=value`` that changes the time is applied when grbl is idle, rejected (error:8) while it moves
        (:meth:`_grbl_setting`), another one counted as ignored; homing, check mode, sleep and reset are
        warned about (their effect is not modelled); reports and the alarm unlock do nothing; anything else is
        grbl's error:3 (invalid statement)."""
        name = kept[:12].decode("latin-1")
        if kept[:3] == b"$J=":
            self._grbl_jog(kept[3:])
            return
        if kept in REPORT_COMMANDS or (kept[:2] == b"$N" and kept[2:3].isdigit() and b"=" in kept):
            self.ignore(name.split("=")[0])        # a report, the unlock, a stored startup line: no motion
            return
        m = _SETTING.fullmatch(kept)
        if m is not None and m.group(2).strip(b"+-.") != b"":
            number = int(float(m.group(1)))
            if number in OTHER_SETTINGS:
                self.ignore(f"${number}")
                return
            if number in TIMING_SETTINGS:
                self._grbl_setting(number, float(m.group(2)), name)
                return
        what = {b"$H": "the homing cycle is not timed (its length depends on where the machine stands) and the "
                       "position after it is not known",
                b"$C": "check mode: grbl checks the lines that follow without moving; they are timed as run",
                b"$SLP": "sleep: grbl stops and powers down; the lines that follow are timed as run"}.get(
            kept[:4] if kept[:4] == b"$SLP" else kept[:2])
        if kept[:5] == b"$RST=":
            what = "reset: grbl restores settings and aborts the motion; the lines that follow are timed as run"
        if what is not None:
            self._grbl_not_modelled(name, f"{name}: {what}")
            return
        self.grbl_reject(3, name)

    def _grbl_setting(self, number: int, value: float, name: str) -> None:
        """``$N=value`` of a setting that changes the time (system.c system_execute_line, settings.c
        settings_store_global_setting): grbl stores it only when idle (error:8 while it moves: the line is
        rejected, the setting unchanged; :meth:`._grbl_idle_after` says when grbl is idle) and refuses a
        negative value (error:4). Applied from that line on: $11 and $110-$122 as a new LIMITS row (the grbl
        model and the policies read it), $12 for the arcs that follow, $32 laser mode. $1 and $100-$102 are
        warned about and not applied (steps/mm: grbl keeps its position in steps, so the position in mm moves
        with the new value; not modelled)."""
        if not self.grbl_idle:
            self.grbl_reject(8, f"{name} while grbl moves (it stores a setting only when idle)")
            return
        if value < 0.0:
            self.grbl_reject(4, f"{name} (a setting is never negative)")
            return
        if number in LIMITS_SETTINGS:
            column, factor = LIMITS_SETTINGS[number]
            if not value > 0.0 and number != 11:
                self.error(f"{name}: a rate or acceleration of 0 stops grbl's planner (it would never end)")
            self._new_limits(**{column: value * factor})
        elif number == 12:
            if not value > 0.0:
                self.error(f"{name}: an arc tolerance of 0 makes grbl cut each arc into endless chords")
            from dataclasses import replace

            self.machine = replace(self.machine, arc_tolerance=value)
        elif number == 32:
            self.grbl_laser = math.trunc(value) != 0        # settings.c: int_value = trunc(value)
            self._grbl_route()
        else:
            what = ("grbl keeps its position in steps: the position in mm moves with the new steps/mm"
                    if number >= 100 else "the idle delay at each stop stays the machine's")
            self._grbl_not_modelled(f"${number}", f"{name}: not applied in a program by gcodeplan ({what}); set "
                                                  f"${number} in the machine")
            return
        self.event(f"{name} applied")

    def _grbl_not_modelled(self, name: str, message: str) -> None:
        """A ``$`` line whose effect on the time is not modelled: one warning naming it, counted as unknown (an
        error under ``--strict``)."""
        if self.strict:
            self.error(message)
        self.warn(message)
        self.unknown[name] = self.unknown.get(name, 0) + 1

    def _grbl_jog(self, body: bytes) -> None:
        """``$J=`` words (gcode.c with its jog flag, jog.c): a G1 at F in the jog's own units and distance mode
        (G20 / G21, G90 / G91, G53 only: else error:16; F required: error:22; other words than X Y Z F N:
        error:36) that leaves the modes as they were. grbl starts a jog only when it is idle or jogging
        (system.c: error:8 while a program's motion runs, as after a motion line with the buffer fed: the line is
        rejected), so it is timed from rest to rest, with one warning per file."""
        pairs, lex_error, what = lex(body)
        words = [Word(k, float(t), t) for k, t in pairs]
        first, _ = grbl_word_error(words)
        if first is None and lex_error:
            first = (lex_error, what, ())
        gs = [round(w.value, 1) for w in words if w.letter == "G"]
        params = {w.letter: w for w in words if w.letter not in "GM"}
        if first is None:
            bad = [f"G{g:g}" for g in gs if g not in _JOG_G] + [f"M{w.text}" for w in words if w.letter == "M"]
            if bad:
                first = (16, f"$J= {' '.join(bad)}", ())
            elif "F" not in params:
                first = (22, "$J= without F", ())
            elif any(k not in "XYZFN" for k in params):
                first = (36, "$J= word(s) " + " ".join(k for k in params if k not in "XYZFN") + " unused", ())
        if first is None and not (self.grbl_idle or self.grbl_jogging):
            first = (8, "$J= while grbl moves (it jogs only when idle)", ())
        if first is not None:
            self.grbl_reject(*first)
            return
        gset = set(gs)
        target = self._grbl_block_target(gset, params)
        unit = 25.4 if 20.0 in gset else 1.0 if 21.0 in gset else float(self.st[S_UNIT])
        self._note_once("$J", "$J= jog: timed as a feed move from rest to rest (grbl starts a jog only when "
                              "idle; its modes stay as they were)")
        self._exact_feed_row(target, params["F"].value * unit / 60.0, "$J")
        self.grbl_idle = False          # jogging: a $ setting now is error:8 (system.c: JOG is not IDLE)
        self.grbl_jogging = True        # another $J= may follow (system.c: JOG state); the next G-code line ends it
        self._grbl_route()
