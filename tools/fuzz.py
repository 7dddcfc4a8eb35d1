#!/usr/bin/env python3
"""Fuzz parse → plan → steps in-process with mutated real G-code.

    python tools/fuzz.py --seed 1 --cases 100000            # a fixed number of cases
    python tools/fuzz.py --seed 7 --seconds 60              # as many as fit in a minute
    python tools/fuzz.py --seed 7 --replay 1234             # run case 1234 of seed 7 again, verbosely
    python tools/fuzz.py --file fuzz_failures/7-1234.gcode  # run a written (minimised) case again
    python tools/fuzz.py --seed 3 --cases 20000 --differential   # interpreted kernels == compiled ones

``--differential`` checks the interpreted path of ``gcodeplan/_jit.py`` instead: every case is planned by
compiled kernels here and by the kernels' Python source in a worker process that has never imported numba
(restarted whenever a fallback imported it), and the MOVE, PLAN and SEGMENT rows, the per-line times and
any error must be identical, field by field and bit for bit.

Each case takes a window of consecutive lines from a real G-code file (``gcode_samples/`` and, when it is
there, ``../shared/gcode/``), mutates some of them (digits, signs, exponents, absurd numbers, comments,
line numbers and checksums, letters, truncation, odd bytes) and splices in generated lines (arcs in the
three planes, canned cycles, work offsets, G92/G10, unit and distance modes, dwells, M204/M201/M203/M205,
Klipper's SET_VELOCITY_LIMIT, G61/G64). The program then runs through :func:`gcodeplan.pipeline.run` for a
random machine (the presets, and Klipper's reference configs when ``../shared`` is there), flavor,
junction policy and, sometimes, an S-curve jerk, with three sinks: time accounting, per-line end times
and step generation (:class:`gcodeplan.stepper.source.StepSink`; skipped once a case would make more than
``--max-steps`` steps, so an absurd 1e9 mm move does not fill memory).

A case *fails* when it raises anything but :class:`gcodeplan.errors.GcodeplanError` (a clear, located
error is the right answer to bad input), or when a planned time (PLAN t_start, phase times, duration,
the total) or a step time is non-finite or negative, or step times of a stepper go backwards. A failing
case is minimised (delta debugging over its lines, keeping the same failure) and written to ``--out``
(``<seed>-<case>.gcode`` with the configuration in its first comment lines, plus a ``.txt`` traceback).

Every case has its own random stream derived from (seed, case number), so ``--replay N`` reproduces
case N alone, whatever ran before it.

Two rounds drive the real command line instead (a subprocess per run, as a user runs it):

    python tools/fuzz.py --signals --seed 3              # one random signal into each command (short)
    python tools/fuzz.py --signals --long --seconds 600  # a longer file, many signals per command
    python tools/fuzz.py --outputs                       # every output option at every kind of path

``--signals`` sends SIGTERM, SIGINT or SIGHUP at a random moment (after gcodeplan's handlers are in place)
into every command that reads G-code, and checks: the exit status is 0 (it finished first) or 128 + n;
standard error is then exactly the one line ``gcodeplan: interrupted`` / ``gcodeplan: terminated by SIGx``;
nothing is left behind (no temporary file, no directory it made, no ``--jobs`` worker) and an output that
existed before is untouched. ``--outputs`` writes every output option to standard output (``-``), a link
to /dev/null, a FIFO, a symbolic link to a file, a full device (``/dev/full``) and a full standard output,
and checks the exit status (0, or 2 with one line for a full device), that a link stays a link, a FIFO a
FIFO and a device a device, that a link's target got the output, and that no temporary file stays.
"""
from __future__ import annotations

import argparse
import math
import os
import random
import re
import sys
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GCODEPLAN_SHARED", REPO.parent / "shared"))

FLAVORS = ("marlin", "klipper", "reprap", "grbl", "linuxcnc")
POLICIES = ("klipper", "junction-deviation", "classic-jerk", "blend", "exact-stop")
PRESETS = ("klipper", "marlin", "grbl")

# bytes read from each big corpus file (a few windows at seeded offsets): enough variety, quick start
POOL_BYTES_PER_FILE = 1 << 20
POOL_WINDOWS_PER_FILE = 4

_NUM = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")

ABSURD = (b"0", b"-0", b"0.0", b"1e9", b"-1e9", b"1e-9", b"1e20", b"-1e20", b"1e308", b"1e-320", b"nan", b"inf",
          b"-inf", b"99999999999999999999", b".", b"-", b"+", b"1.2.3", b"0x10", b"1e", b"--1", b"+-2", b"1_000",
          b"2147483648", b"-2147483649", b"1e400", b"3.4e38", b"0.000001", b"12345.6789",
          # G-code has no exponents (1e-320 is 1 then E-320): absurd magnitudes as decimals, under a float32's
          # smallest (0 in Marlin's and grbl's floats) and past a double's largest
          b"0." + b"0" * 50 + b"1", b"0." + b"0" * 330 + b"1", b"1" + b"0" * 40, b"1" + b"0" * 320, b"0.4")
ODD_BYTES = (b"\t", b"\r", b" ", b"\xc3\xa9", b"\xff", b"\x0b", b"\x0c", b"*", b";", b"(", b")", b"%", b"\\",
             b"=", b"[", b"]", b"{", b"}", b"\"", b"#", b"\x7f")
LETTERS = b"GMXYZEFIJKRPQSTNLDHABCUVW"


# --------------------------------------------------------------------------- corpus
def corpus_files() -> list[Path]:
    """The G-code files the fuzzer draws lines from (text only: binary G-code is left to the reader's tests)."""
    files = []
    for folder in (REPO / "gcode_samples", SHARED / "gcode"):
        if folder.is_dir():
            for p in sorted(folder.iterdir()):
                if p.suffix.lower() in (".gcode", ".ngc", ".nc", ".g") and p.is_file():
                    files.append(p)
    return files


def load_pool(seed: int) -> list[tuple[str, list[bytes]]]:
    """(file name, lines) per corpus file; big files contribute a few windows read at seeded offsets."""
    rng = random.Random(f"pool:{seed}")
    pool = []
    for p in corpus_files():
        size = p.stat().st_size
        with open(p, "rb") as fh:
            if size <= POOL_BYTES_PER_FILE:
                lines = fh.read().splitlines()
            else:
                lines = []
                span = POOL_BYTES_PER_FILE // POOL_WINDOWS_PER_FILE
                for k in range(POOL_WINDOWS_PER_FILE):
                    off = 0 if k == 0 else rng.randrange(0, size - span)
                    fh.seek(off)
                    chunk = fh.read(span).splitlines()
                    lines.extend(chunk[1:-1] if off else chunk[:-1])
        if lines:
            pool.append((p.name, lines))
    if not pool:
        raise SystemExit("fuzz: no corpus files found (gcode_samples/ is empty?)")
    return pool


# --------------------------------------------------------------------------- generated lines
def _n(rng: random.Random, small: bool = False) -> str:
    """A number as G-code writes it: mostly ordinary, sometimes odd."""
    r = rng.random()
    if r < 0.7:
        v = rng.uniform(-5, 5) if small else rng.uniform(-60, 260)
        return f"{v:.{rng.choice((0, 1, 3, 5))}f}"
    if r < 0.85:
        return str(rng.choice((0, 1, -1, 0.5, 10, 100, 0.001)))
    return rng.choice(ABSURD).decode()


def generated_line(rng: random.Random) -> bytes:
    """One generated line exercising the less common parts of the dialects."""
    n = lambda small=False: _n(rng, small)  # noqa: E731
    k = rng.randrange(34)
    if k < 4:   # arcs, centre or radius form, in the current plane, sometimes with turns
        g = rng.choice(("G2", "G3"))
        if rng.random() < 0.6:
            # a consistent arc in relative coordinates: the end lies on the circle around the start + (I, J)
            i_, j_ = rng.uniform(-20, 20), rng.uniform(-20, 20)
            phi = rng.uniform(-6.3, 6.3)
            ex = i_ - (i_ * math.cos(phi) - j_ * math.sin(phi))
            ey = j_ - (i_ * math.sin(phi) + j_ * math.cos(phi))
            f = f" F{rng.choice((60, 600, 1200, 6000))}" if rng.random() < 0.5 else ""
            return f"G91\n{g} X{ex:.4f} Y{ey:.4f} I{i_:.4f} J{j_:.4f}{f}\nG90".encode()
        if rng.random() < 0.3:
            s = f"{g} X{n()} Y{n()} R{n()}"
        else:
            s = f"{g} X{n()} Y{n()} I{n(True)} J{n(True)}"
        if rng.random() < 0.3:
            s += f" Z{n(True)}"
        if rng.random() < 0.2:
            s += f" P{rng.choice((1, 2, 3, 0, -1))}"
        if rng.random() < 0.4:
            s += f" E{n(True)}"
        if rng.random() < 0.5:
            s += f" F{rng.choice((60, 600, 1200, 6000, 30000))}"
        return s.encode()
    if k < 5:
        return rng.choice((b"G17", b"G18", b"G19"))
    if k < 8:   # canned cycles (CNC flavors expand them; printers refuse or ignore)
        g = rng.choice(("G81", "G82", "G83", "G73", "G85", "G89"))
        s = f"{g} X{n()} Y{n()} Z{n(True)} R{n(True)} F{rng.choice((100, 300, 1000))}"
        if g in ("G82", "G89") or rng.random() < 0.2:
            s += f" P{n(True)}"
        if g in ("G83", "G73") or rng.random() < 0.2:
            s += f" Q{n(True)}"
        if rng.random() < 0.2:
            s += f" L{rng.choice((0, 1, 3, -1))}"
        return s.encode()
    if k < 9:
        return rng.choice((b"G80", b"G98", b"G99"))
    if k < 12:  # offsets
        return rng.choice((
            f"G{rng.choice(('54', '55', '56', '57', '58', '59', '59.1', '59.2', '59.3'))}",
            f"G10 L2 P{rng.choice((0, 1, 2, 6, 9))} X{n()} Y{n()} Z{n(True)}",
            f"G10 L20 P1 X{n()} Y{n()}",
            f"G92 X{n()} Y{n()} Z{n(True)} E{n(True)}",
            f"G92 E{n(True)}", "G92.1", "G92.2", "G92.3",
            f"G52 X{n()} Y{n()}",
            "G53 G0 X0 Y0",
        )).encode()
    if k < 14:  # units and modes
        return rng.choice((b"G20", b"G21", b"G90", b"G91", b"M82", b"M83", b"G90.1", b"G91.1", b"G61", b"G61.1",
                           b"G64", f"G64 P{n(True)}".encode(), f"G64 P{n(True)} Q{n(True)}".encode()))
    if k < 16:  # dwells and waits
        return rng.choice((f"G4 P{n()}", f"G4 S{n(True)}", "M400", "G28", "G28 X Y", "M109 S200", "M190 S60",
                           "M0", "M1", "M2", "M30", "M84")).encode()
    if k < 19:  # limits
        return rng.choice((
            f"M204 S{n()}", f"M204 P{n()} T{n()}", f"M204 P{n()}", f"M204 R{n()}",
            f"M201 X{n()} Y{n()} Z{n()} E{n()}", f"M203 X{n()} Y{n()} Z{n(True)} E{n()}",
            f"M205 X{n(True)} Y{n(True)} Z{n(True)} E{n(True)}", f"M205 J{n(True)}",
            f"M220 S{n()}", f"M221 S{n()}", f"M566 X{n()} Y{n()}", f"M92 X{n()} Y{n()} Z{n()} E{n()}",
            f"SET_VELOCITY_LIMIT ACCEL={rng.choice(('1e-320', '1e-46', '1e308', '0.5', '1e39'))}",
            f"SET_VELOCITY_LIMIT VELOCITY={n()} ACCEL={n()}",
            f"SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY={n(True)} MINIMUM_CRUISE_RATIO={n(True)}",
            f"SET_VELOCITY_LIMIT ACCEL_TO_DECEL={n()}",
            "SET_KINEMATIC_POSITION X=0 Y=0 Z=0",
        )).encode()
    if k < 21:  # firmware retraction, tools
        return rng.choice((b"G10", b"G11", b"T0", b"T1", b"M6 T2", f"M207 S{n(True)} F{n()}".encode()))
    # moves with odd values
    g = rng.choice(("G0", "G1", "G1", "G1", "G00", "G01", "g1", ""))
    words = []
    for letter in rng.sample("XYZEF", rng.randrange(1, 5)):
        words.append(f"{letter}{n(letter in 'ZE')}")
    return (g + " " + " ".join(words)).strip().encode()


# --------------------------------------------------------------------------- mutations
def _checksum(body: bytes) -> int:
    c = 0
    for b in body:
        c ^= b
    return c


def mutate_line(line: bytes, rng: random.Random) -> bytes:
    """One mutation of one line."""
    k = rng.randrange(16)
    nums = list(_NUM.finditer(line))
    if k < 3 and nums:          # a digit changed
        m = rng.choice(nums)
        digits = [i for i in range(m.start(), m.end()) if 48 <= line[i] <= 57]
        if digits:
            i = rng.choice(digits)
            return line[:i] + bytes([48 + rng.randrange(10)]) + line[i + 1:]
    if k < 5 and nums:          # sign
        m = rng.choice(nums)
        s = m.group()
        s = s[1:] if s[:1] in b"+-" else rng.choice((b"-", b"+", b"--", b"-+")) + s
        return line[:m.start()] + s + line[m.end():]
    if k < 7 and nums:          # exponent
        m = rng.choice(nums)
        e = rng.choice((b"e5", b"e-5", b"E3", b"e+2", b"e308", b"e-308", b"e", b"e-", b"E999"))
        return line[:m.end()] + e + line[m.end():]
    if k < 9 and nums:          # absurd value
        m = rng.choice(nums)
        return line[:m.start()] + rng.choice(ABSURD) + line[m.end():]
    if k == 9:                  # comments
        i = rng.randrange(len(line) + 1)
        ins = rng.choice((b";", b" ; c", b"(c)", b"(", b")", b"(a(b)c)", b" ;LAYER_CHANGE", b";TYPE:Skirt"))
        return line[:i] + ins + line[i:]
    if k == 10:                 # line number and checksum, right or wrong
        body = b"N%d " % rng.randrange(-2, 100000) + line.split(b";")[0].rstrip()
        c = _checksum(body)
        if rng.random() < 0.3:
            c = (c + rng.randrange(1, 256)) % 256
        return body + b"*%d" % c if rng.random() < 0.9 else body + b"*"
    if k == 11 and line:        # truncated
        return line[:rng.randrange(len(line))]
    if k == 12:                 # odd byte
        i = rng.randrange(len(line) + 1)
        return line[:i] + rng.choice(ODD_BYTES) + line[i:]
    if k == 13:                 # a letter changed, or a word dropped / doubled
        words = line.split(b" ")
        j = rng.randrange(len(words))
        w = words[j]
        r = rng.random()
        if r < 0.4 and w:
            words[j] = bytes([rng.choice(LETTERS)]) + w[1:]
        elif r < 0.7:
            del words[j]
        else:
            words.insert(j, w)
        return b" ".join(words)
    if k == 14:                 # case and spacing
        return rng.choice((line.lower(), line.replace(b" ", b""), line.replace(b" ", b"  \t"), b"  " + line))
    return generated_line(rng)


# --------------------------------------------------------------------------- cases
@dataclass
class Case:
    """One fuzz case: the program (lines without newlines) and the configuration it runs with."""

    seed: int
    index: int
    lines: list[bytes]
    machine: str           # preset name or 'klipper-cfg:<name>'
    flavor: str | None
    policy: str
    jerk: float | None
    origin: str

    def header(self) -> str:
        return (f"; fuzz seed {self.seed} case {self.index}: machine {self.machine}, flavor {self.flavor}, "
                f"policy {self.policy}, jerk {self.jerk}\n; from {self.origin}\n")


def klipper_configs() -> list[Path]:
    ref = SHARED / "reference" / "klipper"
    return [p for p in (ref / "cartesian_corpus.cfg", ref / "corexy_corpus.cfg") if p.exists()]


def make_case(seed: int, index: int, pool, cfgs) -> Case:
    """Case ``index`` of ``seed``: its own random stream, so any case can be replayed alone."""
    rng = random.Random(f"{seed}:{index}")
    name, lines = rng.choice(pool)
    length = rng.choice((1, 2, 3, 5, 8, 13, 21, 34, 60, 120))
    start = rng.randrange(max(1, len(lines) - length + 1))
    prog = list(lines[start:start + length])
    origin = f"{name} lines {start + 1}..{start + len(prog)} of the pool"
    if rng.random() < 0.2:      # a second window, from any file
        name2, lines2 = rng.choice(pool)
        s2 = rng.randrange(max(1, len(lines2) - 10))
        at = rng.randrange(len(prog) + 1)
        prog[at:at] = lines2[s2:s2 + rng.randrange(1, 11)]
        origin += f" + {name2}"
    n_mut = rng.choice((0, 0, 1, 1, 2, 3, 5))
    for _ in range(n_mut):
        if prog and rng.random() < 0.7:
            i = rng.randrange(len(prog))
            prog[i] = mutate_line(prog[i], rng)
        else:
            prog.insert(rng.randrange(len(prog) + 1), generated_line(rng))
    if cfgs and rng.random() < 0.15:
        machine = "klipper-cfg:" + rng.choice(cfgs).name
    else:
        machine = rng.choice(PRESETS)
    flavor = rng.choice((None, None, *FLAVORS))
    policy = rng.choice(POLICIES)
    if policy == "classic-jerk" and machine != "marlin" and rng.random() < 0.8:
        policy = rng.choice(("klipper", "junction-deviation", "blend", "exact-stop"))   # it needs per-axis jerks
    jerk = None
    if policy != "blend" and rng.random() < 0.25:
        jerk = rng.choice((1e3, 1e4, 1e5, 1e6, 3e7))
    return Case(seed, index, prog, machine, flavor, policy, jerk, origin)


# --------------------------------------------------------------------------- running one case
REJECTED = "rejected"


class Bad(Exception):
    """A broken invariant (non-finite / negative time, steps going back in time); ``kind`` names it without
    the values, for grouping failures."""

    def __init__(self, kind: str, detail: str = ""):
        super().__init__(f"{kind} {detail}".strip())
        self.kind = kind


class _Checks:
    """Sinks of one run: time accounting, per-line times and step generation under a step budget."""

    def __init__(self, machine, rails, max_steps: int):
        from gcodeplan.pipeline import LineTimes, Sink
        from gcodeplan.report.summary import TimeSummary
        from gcodeplan.stepper.generate import StepGenerator
        from gcodeplan.stepper.source import homing_resets

        checks = self
        self.time = TimeSummary()
        self.lines = LineTimes()
        self.steps = 0
        self.stepping = True
        self.last_t = [-math.inf] * len(rails)
        # steps per mm of the busiest stepper, times the largest weight (corexy: |x| + |y|)
        self.scale = max((r.steps_per_mm * (sum(abs(w) for w in r.weights) if r.weights else 2.0)
                          for r in rails), default=0.0)
        self.max_steps = max_steps

        def on_steps(si, t, d):
            if t.size:
                if not np.all(np.isfinite(t)):
                    raise Bad(f"non-finite step time on stepper {rails[si].name}")
                if float(t.min()) < 0.0:
                    raise Bad(f"negative step time on stepper {rails[si].name}", repr(float(t.min())))
                back = np.flatnonzero(np.diff(np.r_[checks.last_t[si], t]) < 0.0)
                if back.size:
                    k = int(back[0])
                    prev = checks.last_t[si] if k == 0 else float(t[k - 1])
                    ulps = (prev - float(t[k])) / np.spacing(prev)
                    size = "by rounding (≤ 4 ulp)" if ulps <= 4 else "by more than 4 ulp"
                    raise Bad(f"step times go backwards {size} on stepper {rails[si].name}",
                              f"({prev!r} then {float(t[k])!r})")
                checks.last_t[si] = float(t[-1])
            checks.steps += int(t.size)

        gen = StepGenerator(rails, on_steps, chunk_steps=1 << 14)

        class Steps(Sink):
            def __init__(self):
                self.pending = False

            def add(self, piece):
                checks.check_piece(piece)
                if not checks.stepping:
                    return
                m = piece.moves
                d = (np.abs(m["x1"] - m["x0"]) + np.abs(m["y1"] - m["y0"]) + np.abs(m["z1"] - m["z0"])
                     + np.abs(m["e1"] - m["e0"]))
                with np.errstate(over="ignore"):     # rows near 1e308 mm: an infinite budget skips stepping
                    budget = float(np.sum(d[np.isfinite(d)])) * checks.scale * 2.0 + 4.0 * len(m)
                if not np.all(np.isfinite(d)) or checks.steps + budget > checks.max_steps:
                    checks.stepping = False
                    return
                reset, self.pending = homing_resets(m, piece.segments, piece.first_move, self.pending)
                gen.feed(piece.segments, reset)

            def close(self, result):
                if checks.stepping:
                    gen.finish()

        class Times(Sink):
            def add(self, piece):
                checks.time.add(piece.moves, piece.plan)
                checks.lines.add(piece)

        self.sinks = [Times(), Steps()]

    @staticmethod
    def check_piece(piece) -> None:
        p = piece.plan
        for name in ("t_start", "duration", "accel_t", "cruise_t", "decel_t", "start_v", "cruise_v", "end_v"):
            col = p[name]
            if not np.all(np.isfinite(col)):
                i = int(np.flatnonzero(~np.isfinite(col))[0])
                raise Bad(f"non-finite PLAN.{name}", f"({col[i]!r}) at line {int(piece.moves['line'][i])}")
            if np.any(col < 0.0):
                i = int(np.flatnonzero(col < 0.0)[0])
                raise Bad(f"negative PLAN.{name}", f"({col[i]!r}) at line {int(piece.moves['line'][i])}")
        s = piece.segments
        if s is not None and len(s):
            for name in ("t0", "dt"):
                col = s[name]
                if not np.all(np.isfinite(col)) or np.any(col < 0.0):
                    raise Bad(f"non-finite or negative SEGMENT.{name}")

    def finish(self) -> None:
        total = self.time.end_t
        if not (math.isfinite(total) and total >= 0.0):
            raise Bad("non-finite or negative total time", repr(total))
        _, ends = self.lines.arrays()
        if ends.size and (not np.all(np.isfinite(ends)) or np.any(ends < 0.0)):
            raise Bad("non-finite or negative per-line end time")


_MACHINES: dict = {}
_RAILS: dict = {}
FUZZ_CHUNK_BYTES = 4096


@contextmanager
def _small_reads():
    """Read sources in small chunks while planning one case: a fresh 8 MB read buffer per case would cost more
    than the case, and small chunks also put lines across chunk boundaries. The reader's chunk size is a
    keyword default; it is put back on leaving, so a process that fuzzes (the test suite) reads as before."""
    from gcodeplan.gcode.reader import GcodeReader

    kw = GcodeReader.__init__.__kwdefaults__
    old = kw.get("chunk_bytes") if kw else None
    if old is not None:
        kw["chunk_bytes"] = FUZZ_CHUNK_BYTES
    try:
        yield
    finally:
        if old is not None:
            kw["chunk_bytes"] = old


def _machine(case: Case):
    import gcodeplan as gp

    key = (case.machine, case.flavor)
    if key not in _MACHINES:
        if case.machine.startswith("klipper-cfg:"):
            cfg = SHARED / "reference" / "klipper" / case.machine.split(":", 1)[1]
            _MACHINES[key] = gp.load_machine(klipper_config=str(cfg), flavor=case.flavor)
        else:
            _MACHINES[key] = gp.load_machine(case.machine, flavor=case.flavor)
    return _MACHINES[key]


def run_case(case: Case, lines: list[bytes] | None = None, max_steps: int = 2_000_000):
    """Run one case: None when it passes, ``REJECTED`` when it raised a GcodeplanError (a clear error is a
    pass too), else (signature, traceback text)."""
    from gcodeplan.errors import GcodeplanError

    lines = case.lines if lines is None else lines
    try:
        with _small_reads():
            return _run_case(case, lines, max_steps)
    except GcodeplanError:
        return REJECTED
    except Bad as err:
        return f"Bad: {err.kind}", traceback.format_exc()
    except Exception as err:  # noqa: BLE001 - every other exception is what we are looking for
        tb = traceback.extract_tb(err.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?"
        return f"{type(err).__name__} at {where}", traceback.format_exc()


def _run_case(case: Case, lines: list[bytes], max_steps: int) -> None:
    """Plan and step one case through every check (run_case's body; raises what it finds)."""
    from gcodeplan.pipeline import run
    from gcodeplan.stepper.source import rails_from

    machine = _machine(case)
    key = (case.machine, case.flavor)
    if key not in _RAILS:
        _RAILS[key] = rails_from(machine)
    checks = _Checks(machine, _RAILS[key], max_steps)
    run([ln + b"\n" for ln in lines], machine, policy=case.policy, jerk=case.jerk, sinks=checks.sinks,
        batch_moves=512)
    checks.finish()


# --------------------------------------------------------------------------- interpreted == compiled
def plan_digest(case: Case) -> str:
    """sha256 of what planning ``case`` gives: every field of the MOVE, PLAN and SEGMENT rows and the per-line
    end times as bytes, or the GcodeplanError's text (padding bytes of the aligned dtypes are left out)."""
    import hashlib

    from gcodeplan.errors import GcodeplanError
    from gcodeplan.pipeline import Collect, LineTimes, run

    h = hashlib.sha256()
    try:
        collect, times = Collect(segments=True), LineTimes()
        with _small_reads():
            run([ln + b"\n" for ln in case.lines], _machine(case), policy=case.policy, jerk=case.jerk,
                sinks=[collect, times], batch_moves=512)
        for arr in (*collect.arrays(), *times.arrays()):
            names = arr.dtype.names or (None,)
            for name in names:
                col = arr if name is None else arr[name]
                h.update(np.ascontiguousarray(col).tobytes())
    except GcodeplanError as err:
        h.update(b"error: " + str(err).encode())
    return h.hexdigest()


def interpreted_worker(seed: int) -> int:
    """Read case numbers on stdin; answer ``<case> <digest> <numba imported 0/1>`` per line, planning each
    case with the kernels interpreted (exits after a case that imported numba: the parent restarts it)."""
    from gcodeplan import _jit

    pool, cfgs = load_pool(seed), klipper_configs()
    for line in sys.stdin:
        i = int(line)
        case = make_case(seed, i, pool, cfgs)
        _jit._interpreted_s = 0.0           # each case gets the budget a fresh process would have
        with _jit.interpreted():
            try:
                digest = plan_digest(case)
            except Exception as err:  # noqa: BLE001 - reported as its own digest, the parent shows it
                digest = f"exception:{type(err).__name__}"
        sys.stdout.write(f"{i} {digest} {int(_jit.active())}\n")
        sys.stdout.flush()
        if _jit.active():
            return 0
    return 0


def differential(seed: int, cases: int | None, seconds: float | None, start: int = 0, log=print) -> Stats:
    """Cases ``start``… planned compiled here and interpreted in a worker; a differing digest is a failure
    (``Stats.signatures``: 'interpreted != compiled' → first case). ``Stats.rejected`` counts the cases whose
    interpreted run fell back to numba (they are compared all the same)."""
    import subprocess

    from gcodeplan import _jit

    _jit.activate()
    pool, cfgs = load_pool(seed), klipper_configs()
    cmd = [sys.executable, str(Path(__file__).resolve()), "--seed", str(seed), "--interpreted-worker"]
    worker = None
    st = Stats()
    t0 = time.monotonic()
    i = start
    try:
        while (cases is None or st.cases < cases) and (seconds is None or time.monotonic() - t0 < seconds):
            if worker is None:
                worker = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            worker.stdin.write(f"{i}\n")
            worker.stdin.flush()
            c0 = time.monotonic()
            try:
                compiled = plan_digest(make_case(seed, i, pool, cfgs))
            except Exception as err:  # noqa: BLE001
                compiled = f"exception:{type(err).__name__}"
            answer = worker.stdout.readline().split()
            if len(answer) != 3:
                raise SystemExit(f"fuzz: the interpreted worker died at case {i}")
            dt = time.monotonic() - c0
            if dt > st.slowest[0]:
                st.slowest = (dt, i)
            st.cases += 1
            if answer[2] == "1":
                st.rejected += 1
                worker.stdin.close()
                worker.wait()
                worker = None
            if answer[1] != compiled:
                st.failures += 1
                sig = "interpreted != compiled"
                st.counts[sig] = st.counts.get(sig, 0) + 1
                st.signatures.setdefault(sig, (i, f"--seed {seed} --replay {i}"))
                log(f"case {i}: interpreted {answer[1][:16]} != compiled {compiled[:16]}")
            i += 1
    finally:
        if worker is not None:
            worker.stdin.close()
            worker.wait()
    st.seconds = time.monotonic() - t0
    return st


# --------------------------------------------------------------------------- minimising
def minimise(case: Case, signature: str, max_steps: int, budget_s: float = 60.0) -> list[bytes]:
    """Delta debugging (Zeller's ddmin) over the lines: a smallest-found subset with the same failure."""
    deadline = time.monotonic() + budget_s

    def fails(lines):
        res = run_case(case, lines, max_steps)
        return isinstance(res, tuple) and res[0] == signature

    lines = list(case.lines)
    n = 2
    while len(lines) >= 2 and time.monotonic() < deadline:
        size = math.ceil(len(lines) / n)
        chunks = [lines[i:i + size] for i in range(0, len(lines), size)]
        reduced = False
        for i in range(len(chunks)):
            complement = [ln for j, c in enumerate(chunks) if j != i for ln in c]
            if complement and fails(complement):
                lines = complement
                n = max(n - 1, 2)
                reduced = True
                break
        if not reduced:
            if n >= len(lines):
                break
            n = min(len(lines), 2 * n)
    return lines


def read_case(path: Path) -> Case:
    """A case file written by :func:`write_failure`: its configuration from the first comment line."""
    raw = Path(path).read_bytes().splitlines()
    m = re.match(rb"; fuzz seed (-?\d+) case (\d+): machine (\S+), flavor (\S+), policy (\S+), jerk (\S+)", raw[0])
    if not m:
        raise SystemExit(f"{path}: not a fuzz case (first line)")
    seed, index, machine, flavor, policy, jerk = (g.decode() for g in m.groups())
    lines = [ln for ln in raw[1:] if not ln.startswith((b"; from ", b"; failure: "))]
    return Case(int(seed), int(index), lines, machine.rstrip(","), None if flavor == "None," else flavor.rstrip(","),
                policy.rstrip(","), None if jerk == "None" else float(jerk), str(path))


def write_failure(out: Path, case: Case, signature: str, tb: str, lines: list[bytes]) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    base = out / f"{case.seed}-{case.index}"
    with open(base.with_suffix(".gcode"), "wb") as fh:
        fh.write(case.header().encode())
        fh.write(f"; failure: {signature}\n".encode())
        for ln in lines:
            fh.write(ln + b"\n")
    base.with_suffix(".txt").write_text(f"{signature}\n{case.header()}\n{tb}")
    return base.with_suffix(".gcode")


# --------------------------------------------------------------------------- driver
@dataclass
class Stats:
    """Counts of a fuzz round."""

    cases: int = 0
    rejected: int = 0              # GcodeplanError: a clear error, a pass
    failures: int = 0
    signatures: dict = field(default_factory=dict)   # signature -> first (case index, written file)
    counts: dict = field(default_factory=dict)       # signature -> failing cases
    seconds: float = 0.0
    slowest: tuple = (0.0, -1)

    def line(self) -> str:
        return (f"{self.cases} cases in {self.seconds:.0f} s ({self.cases / max(self.seconds, 1e-9):.0f}/s), "
                f"{self.rejected} refused with a GcodeplanError: {self.failures} failures "
                f"({len(self.signatures)} distinct), slowest case {self.slowest[1]} {self.slowest[0]:.2f} s")


def fuzz(seed: int, cases: int | None, seconds: float | None, out: Path, max_steps: int = 2_000_000,
         start: int = 0, log=print, minimise_s: float = 60.0) -> Stats:
    """Run cases start, start+1, … until ``cases`` ran or ``seconds`` passed; failures minimised into ``out``."""
    pool = load_pool(seed)
    cfgs = klipper_configs()
    st = Stats()
    t0 = time.monotonic()
    last_log = t0
    i = start
    while True:
        now = time.monotonic()
        if cases is not None and st.cases >= cases:
            break
        if seconds is not None and now - t0 >= seconds:
            break
        case = make_case(seed, i, pool, cfgs)
        c0 = time.monotonic()
        res = run_case(case, max_steps=max_steps)
        dt = time.monotonic() - c0
        if dt > st.slowest[0]:
            st.slowest = (dt, i)
        st.cases += 1
        if res == REJECTED:
            st.rejected += 1
        elif res is not None:
            st.failures += 1
            sig, tb = res
            st.counts[sig] = st.counts.get(sig, 0) + 1
            if sig not in st.signatures:
                small = minimise(case, sig, max_steps, minimise_s)
                path = write_failure(out, case, sig, tb, small)
                st.signatures[sig] = (i, str(path))
                log(f"case {i}: {sig} -> {path} ({len(small)} lines)")
        i += 1
        if now - last_log > 60:
            last_log = now
            st.seconds = now - t0
            log(f"[{time.strftime('%H:%M:%S')}] up to case {i}: {st.line()}")
    st.seconds = time.monotonic() - t0
    return st


# --------------------------------------------------------------------------- the command line: signals, outputs
SIGNAL_NAMES = ("SIGTERM", "SIGINT", "SIGHUP")


def _cli_env() -> dict:
    """The environment of a CLI run: this checkout's sources first."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src")] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
                                                                 if p])
    return env


def _cli(argv, cwd, env=None, **kw):
    import subprocess

    return subprocess.Popen([sys.executable, "-m", "gcodeplan.cli", *map(str, argv)], cwd=cwd,
                            env=env or _cli_env(), **kw)


def zigzag_file(path: Path, moves: int) -> Path:
    """A printer program of ``moves`` long zig-zag moves (planning and stepping take about a second a 300 000)."""
    block = "".join(f"G1 X{(i % 2) * 180 + 10:.0f} Y{10 + (i % 1800) * 0.1:.1f} E0.5 F12000\n" for i in range(3600))
    with open(path, "w") as fh:
        fh.write(";LAYER_CHANGE\n;Z:0.2\nG90\nM83\nG1 Z0.2 F600\n")
        for _ in range(max(moves // 3600, 1)):
            fh.write(block)
    return path


def _handlers_in_place(pid: int) -> bool:
    import signal

    try:
        with open(f"/proc/{pid}/status") as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught >> (signal.SIGTERM - 1) & 1)


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(x) for x in fh.read().split()]
    except OSError:
        return []


def signal_commands(src: Path, src2: Path, out: Path) -> list[tuple[str, list, list[str]]]:
    """(label, argv, output names in ``out`` that exist beforehand with "previous" in them)."""
    return [
        ("estimate", ["estimate", src], []),
        ("estimate --json --per-line", ["estimate", src, "--json", "--per-line", out / "l.csv"], ["l.csv"]),
        ("estimate --jobs 2", ["estimate", "--jobs", "2", src, src2], []),
        ("parse", ["parse", src], []),
        ("steps", ["steps", src, "-o", out / "s.npz", "-q"], ["s.npz"]),
        ("steps --csv --compress", ["steps", src, "-o", out / "s.npz", "--csv", out / "csv" / "new", "--compress",
                                    "-q"], ["s.npz"]),
        ("report", ["report", src, "-o", out / "r.html", "--slowest", "1"], ["r.html"]),
        ("view", ["view", src, "-o", out / "v.html"], ["v.html"]),
        ("post-process", ["post-process", src, "-o", out / "p.gcode", "-q"], ["p.gcode"]),
        ("dump-moves", ["dump-moves", src, "-o", out / "m.csv"], ["m.csv"]),
        ("plot layers", ["plot", src, "-o", out / "p.png", "--what", "layers"], ["p.png"]),
    ]


def signal_round(seed: int, rounds: int = 1, moves: int = 300_000, max_delay_s: float = 3.0, work: Path | None = None,
                 seconds: float | None = None, log=print, cold: bool = False) -> dict:
    """Signal every command of :func:`signal_commands` ``rounds`` times (or until ``seconds``) at a random moment;
    returns {"runs", "signalled", "finished_first", "failures": [text, …]}. ``cold``: every run starts with an
    empty numba cache (NUMBA_CACHE_DIR), so signals land inside numba's compiler and its callbacks from C."""
    import shutil
    import signal
    import subprocess
    import tempfile

    rng = random.Random(seed)
    own = work is None
    work = Path(tempfile.mkdtemp(prefix="gcodeplan-fuzz-signals-")) if own else Path(work)
    work.mkdir(parents=True, exist_ok=True)
    stats = {"runs": 0, "signalled": 0, "finished_first": 0, "failures": []}
    t_end = None if seconds is None else time.monotonic() + seconds
    try:
        inputs = work / "in"
        inputs.mkdir(exist_ok=True)
        src = zigzag_file(inputs / "a.gcode", moves)
        src2 = zigzag_file(inputs / "b.gcode", moves // 3)
        r = 0
        while r < rounds or t_end is not None:
            if t_end is not None and time.monotonic() > t_end:
                break
            for label, argv, existing in signal_commands(src, src2, work / "out"):
                out = work / "out"
                shutil.rmtree(out, ignore_errors=True)
                out.mkdir()
                for name in existing:
                    (out / name).write_bytes(b"previous")
                sig = getattr(signal, rng.choice(SIGNAL_NAMES))
                delay = rng.uniform(0.0, max_delay_s)
                what = f"{label} [{signal.Signals(sig).name} after {delay:.2f} s]"
                env = None
                if cold:
                    env = dict(_cli_env(), NUMBA_CACHE_DIR=str(work / "numba-cache"))
                    shutil.rmtree(work / "numba-cache", ignore_errors=True)
                proc = _cli(argv, out, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
                workers: set[int] = set()
                sent = False
                try:
                    t0 = time.monotonic()
                    while not _handlers_in_place(proc.pid) and proc.poll() is None and time.monotonic() - t0 < 120:
                        time.sleep(0.005)
                    t1 = time.monotonic()
                    while proc.poll() is None and time.monotonic() - t1 < delay:
                        workers.update(_children(proc.pid))
                        time.sleep(0.005)
                    if proc.poll() is None:
                        workers.update(_children(proc.pid))
                        proc.send_signal(sig)
                        sent = True
                    err = proc.communicate(timeout=300)[1]
                except subprocess.TimeoutExpired:
                    proc.kill()
                    err = proc.communicate()[1]
                    stats["failures"].append(f"{what}: did not end within 300 s of the signal")
                    continue
                stats["runs"] += 1
                rc = proc.returncode
                problems = []
                if rc == 0:
                    stats["finished_first"] += 1
                elif rc == 128 + sig and sent:
                    stats["signalled"] += 1
                    want = "gcodeplan: interrupted" if sig == signal.SIGINT else \
                        f"gcodeplan: terminated by {signal.Signals(sig).name}"
                    if err.splitlines() != [want]:
                        problems.append(f"stderr is not the one line {want!r}: {err[-600:]!r}")
                    for name in existing:
                        if (out / name).read_bytes() != b"previous" and not (out / name).stat().st_size > 8:
                            problems.append(f"{name} half-written")
                    made = sorted(set(os.listdir(out)) - set(existing))
                    if made:
                        problems.append(f"left behind: {made}")
                else:
                    problems.append(f"exit status {rc} (want 0 or {128 + sig}): {err[-600:]!r}")
                hidden = [n for n in os.listdir(out) if n.startswith(".")]
                if hidden:
                    problems.append(f"temporary files left: {hidden}")
                time.sleep(0.05)
                alive = [pid for pid in workers if os.path.exists(f"/proc/{pid}")
                         and "gcodeplan" in _cmdline(pid)]
                if alive:
                    problems.append(f"workers still running: {alive}")
                    for pid in alive:
                        with contextlib_suppress():
                            os.kill(pid, signal.SIGKILL)
                for p in problems:
                    stats["failures"].append(f"{what}: {p}")
                    log(f"FAIL {what}: {p}")
            r += 1
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    return stats


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode("utf-8", "replace")
    except OSError:
        return ""


def contextlib_suppress():
    import contextlib

    return contextlib.suppress(OSError)


OUTPUT_COMMANDS = (
    # (label, argv with {o} for the output, what the output starts with, the output's usual ending)
    ("post-process -o", ["post-process", "{f}", "-o", "{o}", "-q"], b"M73 P0", ".gcode"),
    ("dump-moves -o", ["dump-moves", "{f}", "-o", "{o}"], b"line,kind,", ".csv"),
    ("estimate --per-line", ["estimate", "{f}", "--per-line", "{o}", "--quiet"], b"source_line,end_time_s", ".csv"),
    ("report -o", ["report", "{f}", "-o", "{o}", "--slowest", "0"], b"<!DOCTYPE html>", ".html"),
    ("view -o", ["view", "{f}", "-o", "{o}"], b"<!DOCTYPE html>", ".html"),
    ("plot -o", ["plot", "{f}", "-o", "{o}", "--what", "path"], b"\x89PNG", ".png"),
    ("steps -o", ["steps", "{f}", "-o", "{o}", "-q"], b"PK", ".npz"),
    ("profile --plot", ["profile", "--distance", "10", "--v-max", "100", "--a-max", "1000", "--plot", "{o}"],
     b"\x89PNG", ".png"),
)
STDOUT_COMMANDS = (["estimate", "{f}"], ["estimate", "{f}", "--json"], ["parse", "{f}"], ["parse", "{f}", "--json"],
                   ["estimate", "--jobs", "2", "{f}", "{f}"])
OUTPUT_KINDS = ("stdout", "devnull-link", "fifo", "file-link", "full-device")


def output_round(work: Path | None = None, log=print, kinds=OUTPUT_KINDS, commands=OUTPUT_COMMANDS,
                 stdout_commands=STDOUT_COMMANDS) -> dict:
    """Every output option of :data:`OUTPUT_COMMANDS` at every kind of path, plus the commands that print to a
    full standard output; returns {"runs", "failures": [text, …]}."""
    import shutil
    import stat
    import subprocess
    import tempfile
    import threading

    own = work is None
    work = Path(tempfile.mkdtemp(prefix="gcodeplan-fuzz-outputs-")) if own else Path(work)
    work.mkdir(parents=True, exist_ok=True)
    stats = {"runs": 0, "failures": []}
    program = "G28\nG1 X10 Y10 F3000\nG1 X20 E1\nG1 X30 Y5 E2\n"
    full = "/dev/full" if os.path.exists("/dev/full") else None

    def fail(what, text):
        stats["failures"].append(f"{what}: {text}")
        log(f"FAIL {what}: {text}")

    try:
        src = work / "a.gcode"
        src.write_text(program)
        for label, argv, head, ext in commands:
            for kind in kinds:
                if kind == "full-device" and full is None:
                    continue
                what = f"{label} at {kind}"
                d = work / "o"
                shutil.rmtree(d, ignore_errors=True)
                d.mkdir()
                real = d / ("real" + ext)
                got: list[bytes] = []
                reader = None
                if kind == "stdout":
                    target = "-"
                elif kind == "devnull-link":
                    target = d / "null"
                    os.symlink(os.devnull, target)
                elif kind == "fifo":
                    target = d / "pipe"
                    os.mkfifo(target)
                    reader = threading.Thread(target=lambda t=target: got.append(open(t, "rb").read()), daemon=True)
                    reader.start()
                elif kind == "file-link":
                    real.write_bytes(b"previous")
                    os.chmod(real, 0o640)
                    target = d / ("link" + ext)
                    os.symlink(real.name, target)
                else:
                    target = d / "full"
                    os.symlink(full, target)      # a link to the full device: written as a stream, never replaced
                before = os.lstat(target).st_mode if kind != "stdout" else None
                proc = _cli([a.format(f=src, o=target) for a in argv], d, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
                try:
                    out, err = proc.communicate(timeout=300)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    out, err = proc.communicate()
                    fail(what, "did not end within 300 s")
                    continue
                if reader is not None:
                    reader.join(30)
                    if reader.is_alive():       # nobody opened the FIFO: unblock the reader
                        with contextlib_suppress():
                            os.close(os.open(target, os.O_WRONLY | os.O_NONBLOCK))
                stats["runs"] += 1
                errs = err.decode("utf-8", "replace")
                if "Traceback" in errs:
                    fail(what, f"traceback: {errs[-600:]!r}")
                    continue
                if kind == "full-device":
                    if proc.returncode != 2 or len(errs.strip().splitlines()) != 1 or "No space left" not in errs:
                        fail(what, f"want exit 2 and one line naming the full device, got {proc.returncode}: {errs!r}")
                elif proc.returncode != 0:
                    fail(what, f"exit status {proc.returncode}: {errs[-600:]!r}")
                    continue
                if kind != "stdout":
                    now = os.lstat(target).st_mode
                    if stat.S_IFMT(now) != stat.S_IFMT(before):
                        fail(what, f"{target.name} was replaced: it was {stat.filemode(before)}, now {stat.filemode(now)}")
                if kind == "stdout" and not out.startswith(head):
                    fail(what, f"standard output starts {out[:40]!r}, want {head!r}")
                if kind == "fifo" and not (got and got[0].startswith(head)):
                    fail(what, f"the FIFO's reader got {got[0][:40] if got else None!r}, want {head!r}")
                if kind == "file-link":
                    if not real.read_bytes().startswith(head):
                        fail(what, "the link's target did not get the output")
                    if stat.S_IMODE(os.stat(real).st_mode) != 0o640:
                        fail(what, "the target's permissions changed")
                leftovers = [n for n in os.listdir(d) if n.startswith(".") or n == "-"]
                if leftovers:
                    fail(what, f"left behind: {leftovers}")
        for argv in stdout_commands if full else ():
            what = " ".join(argv).replace("{f}", "FILE") + " > /dev/full"
            with open(full, "wb") as sink:
                proc = _cli([a.format(f=src) for a in argv], work, stdout=sink, stderr=subprocess.PIPE)
                errs = proc.communicate(timeout=300)[1].decode("utf-8", "replace")
            stats["runs"] += 1
            if proc.returncode != 2 or errs.strip().splitlines() != [
                    "gcodeplan: cannot write standard output: No space left on device"]:
                fail(what, f"want exit 2 and one line, got {proc.returncode}: {errs[-600:]!r}")
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    return stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=int, default=None, help="number of cases (default: unlimited with --seconds)")
    ap.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    ap.add_argument("--start", type=int, default=0, help="first case number (to split a round across processes)")
    ap.add_argument("--out", type=Path, default=Path("fuzz_failures"), help="folder for minimised failing cases")
    ap.add_argument("--max-steps", type=int, default=2_000_000, help="skip stepping a case beyond this many steps")
    ap.add_argument("--replay", type=int, default=None, help="run this one case and print it")
    ap.add_argument("--file", type=Path, default=None, help="run a case written to --out again (minimised or edited)")
    ap.add_argument("--differential", action="store_true",
                    help="compare interpreted kernels with compiled ones instead (gcodeplan/_jit.py)")
    ap.add_argument("--interpreted-worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--signals", action="store_true",
                    help="signal round: a random SIGTERM/SIGINT/SIGHUP into each command (see the module doc)")
    ap.add_argument("--outputs", action="store_true",
                    help="output-path round: every output option at -, /dev/null, a FIFO, a link, a full device")
    ap.add_argument("--cold", action="store_true",
                    help="--signals: each run with an empty numba cache (signals land in the compiler)")
    ap.add_argument("--long", action="store_true",
                    help="--signals: a 4x longer file and 5 signals per command (default: one, short; --seconds "
                         "runs rounds until then)")
    args = ap.parse_args(argv)
    if args.signals or args.outputs:
        failures = []
        if args.outputs:
            st = output_round()
            print(f"outputs: {st['runs']} runs, {len(st['failures'])} failures")
            failures += st["failures"]
        if args.signals:
            st = signal_round(args.seed, rounds=5 if args.long else 1, moves=1_200_000 if args.long else 300_000,
                              max_delay_s=10.0 if args.long else 3.0, seconds=args.seconds, cold=args.cold)
            print(f"signals: {st['runs']} runs, {st['signalled']} stopped by the signal, {st['finished_first']} "
                  f"finished first, {len(st['failures'])} failures")
            failures += st["failures"]
        for f in failures:
            print("  " + f)
        return 1 if failures else 0
    if args.interpreted_worker:
        return interpreted_worker(args.seed)
    if args.differential:
        if args.cases is None and args.seconds is None:
            args.cases = 1000
        st = differential(args.seed, args.cases, args.seconds, args.start)
        print(f"seed {args.seed}, cases {args.start}..{args.start + st.cases - 1}: {st.cases} cases in "
              f"{st.seconds:.0f} s, {st.rejected} fell back to numba in the interpreted run, {st.failures} differ")
        return 1 if st.failures else 0
    if args.file is not None:
        case = read_case(args.file)
        res = run_case(case, max_steps=args.max_steps)
        print(res[1] if isinstance(res, tuple) else ("PASS" if res is None else "PASS (rejected: GcodeplanError)"))
        return 1 if isinstance(res, tuple) else 0
    if args.cases is None and args.seconds is None and args.replay is None:
        args.cases = 1000
    if args.replay is not None:
        case = make_case(args.seed, args.replay, load_pool(args.seed), klipper_configs())
        sys.stdout.write(case.header())
        for ln in case.lines:
            sys.stdout.write(ln.decode("utf-8", "replace") + "\n")
        res = run_case(case, max_steps=args.max_steps)
        print(res[1] if isinstance(res, tuple) else ("PASS" if res is None else "PASS (rejected: GcodeplanError)"))
        return 1 if isinstance(res, tuple) else 0
    st = fuzz(args.seed, args.cases, args.seconds, args.out, args.max_steps, args.start)
    print(f"seed {args.seed}, cases {args.start}..{args.start + st.cases - 1}: {st.line()}")
    for sig, (i, path) in st.signatures.items():
        print(f"  {sig}: {st.counts[sig]} cases, first case {i}, minimised in {path}")
    return 1 if st.failures else 0


if __name__ == "__main__":
    sys.exit(main())
