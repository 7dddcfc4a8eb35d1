"""The public API behind ``import gcodeplan``: machines, estimates, plans and steps in a few calls.

Every function takes a *source* — a path, ``'-'`` (standard input), a file object, or an iterable of
lines — and a machine (:func:`load_machine`; None = the ``klipper`` preset). Units: mm, s, mm/s,
mm/s², mm/s³. Errors are :class:`gcodeplan.errors.GcodeplanError` naming file and line.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import pipeline


def load_machine(spec: str | None = None, *, klipper_config: str | None = None, linuxcnc_ini: str | None = None,
                 flavor: str | None = None, firmware: str | None = None):
    """A :class:`~gcodeplan.machine.Machine`: a preset name (``klipper``, ``marlin``, ``grbl``), a machine
    ``.toml`` path, or ``klipper_config=`` a Klipper ``printer.cfg`` (includes followed; the G-code then
    has Klipper's meanings), or ``linuxcnc_ini=`` a LinuxCNC machine ``.ini`` (planned with the ``linuxcnc``
    policy). ``flavor`` overrides the G-code dialect; ``firmware`` the firmware model (``grbl-1.1``,
    ``marlin-2.1.2``, ``marlin-bugfix``, ``klipper`` or ``linuxcnc`` (the policy of that name), or ``generic`` for
    the junction policy alone). Default: the ``klipper`` preset.
    Its limits are in mm, mm/s, mm/s² (docs/machine.md lists every key)."""
    from dataclasses import replace

    from .config import load_klipper_config
    from .config import load_machine as load
    from .errors import ConfigError

    if sum(x is not None for x in (spec, klipper_config, linuxcnc_ini)) > 1:
        raise ConfigError("give one of a machine, klipper_config= or linuxcnc_ini=")
    if klipper_config is not None:
        machine = load_klipper_config(str(klipper_config))
    elif linuxcnc_ini is not None:
        from .config.linuxcnc import load_linuxcnc_ini

        machine = load_linuxcnc_ini(str(linuxcnc_ini))
    else:
        machine = load(spec or "klipper")
        if spec is None and flavor is None:
            machine = replace(machine, auto_flavor=True)   # the default: a CNC program may pick its flavor (gcode/dialect.py)
    if flavor is not None:
        from .machine import FLAVORS

        if flavor not in FLAVORS:
            raise ConfigError(f"flavor: unknown value {flavor!r} (one of {', '.join(FLAVORS)})")
        machine = replace(machine, flavor=flavor)
    if firmware is not None:
        from .machine import FIRMWARES, with_firmware

        if firmware not in FIRMWARES:
            raise ConfigError(f"firmware: unknown value {firmware!r} (one of {', '.join(FIRMWARES)})")
        machine = with_firmware(machine, firmware)
    return machine


def as_machine(machine):
    """A Machine from a Machine, a preset name or .toml path, or None (the klipper preset)."""
    return load_machine() if machine is None else (load_machine(machine) if isinstance(machine, str) else machine)


class _EstimateSink(pipeline.Sink):
    """Time accounting and (when asked) per-line end times of one run."""

    def __init__(self, line_times: bool = True):
        from .report.summary import TimeSummary

        self.time = TimeSummary()
        self.lines = pipeline.LineTimes() if line_times else None

    def add(self, piece: pipeline.Piece) -> None:
        self.time.add(piece.moves, piece.plan)
        if self.lines is not None:
            self.lines.add(piece)


def estimate(source, machine=None, policy: str | None = None, jerk: float | None = None, *, strict: bool = False,
             progress=None, exclude_objects=(), line_times: bool = True):
    """Plan ``source`` and account for its time: an :class:`~gcodeplan.report.estimate.Estimate`.

    ``est.total_time_s`` (s), ``est.to_json()`` (what ``gcodeplan estimate --json`` prints),
    ``est.line_times()`` ((line, end_time_s) arrays, Klipper's per-line CSV), ``est.to_text()``.
    ``policy``: junction policy name (None = the machine's); ``jerk``: path jerk limit (mm/s³) for
    S-curves; ``strict``: unknown commands are errors; ``progress(bytes_done)`` as the work advances
    (the input bytes whose moves are planned: :func:`gcodeplan.pipeline.run`);
    ``exclude_objects``: object names cancelled as Klipper's exclude_object runs them; ``line_times``: False
    keeps no per-line end times (16 bytes per line: 30 MB and a few tenths of a second on a 50 MB file), and
    ``est.line_times()`` then raises.
    """
    from .machine import planned_by
    from .report.estimate import Estimate

    machine = as_machine(machine)
    sink = _EstimateSink(line_times)
    res = pipeline.run(source, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink], progress=progress,
                       exclude_objects=exclude_objects)
    r = res.reader
    return Estimate(res.name, r.summary, sink.time, list(r.layer_z), list(r.features), res.policy, machine.name,
                    line_ends=sink.lines.arrays() if sink.lines is not None else (None, None), objects=list(r.interp.objects.names),
                    wait_time_s=dict(r.interp.wait_time_s),
                    filament_diameter_mm=r.interp.filament_diameter_mm,   # the E figures' filament (M200 / UltiGCode)
                    firmware=planned_by(machine, res.policy, jerk))


@dataclass
class Plan:
    """A whole program planned, in memory (for programs that fit: ~400 bytes per move).

    ``moves`` (MOVE rows), ``plan`` (PLAN rows, 1:1 with ``moves``: speeds mm/s, phase times s,
    ``t_start`` s), ``segments`` (SEGMENT rows: per-axis cubic pieces in time), ``limits`` (the LIMITS
    table the moves index), ``layer_z`` (mm per layer), ``features`` (feature names), ``summary`` (the
    parser's counts), ``policy`` and ``mode`` ('trapezoid', 'scurve' or 'blend').
    """

    moves: np.ndarray
    plan: np.ndarray
    segments: np.ndarray
    limits: np.ndarray
    layer_z: list = field(default_factory=list)
    features: list = field(default_factory=list)
    summary: object = None
    policy: str = ""
    mode: str | None = None

    @property
    def total_time_s(self) -> float:
        """End of the last move (s)."""
        if len(self.plan) == 0:
            return 0.0
        return float(self.plan["t_start"][-1] + self.plan["duration"][-1])

    def sample(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(position mm, velocity mm/s, acceleration mm/s², jerk mm/s³) at ``times`` (s), each of shape
        (len(times), 4) for x, y, z, e: the plan's own polynomial pieces evaluated exactly. Times
        outside the plan hold the first / last position at rest. ``times`` must be sorted ascending
        (``np.sort`` them first) and not NaN: otherwise a ValueError names the first entry out of order."""
        from .planner.sampling import sample_segments

        return sample_segments(self.segments, np.asarray(times, dtype=np.float64))

    def line_times(self) -> tuple[np.ndarray, np.ndarray]:
        """(line, end_time_s) as :meth:`Estimate.line_times <gcodeplan.report.estimate.Estimate.line_times>`."""
        lt = pipeline.LineTimes()
        lt.add(pipeline.Piece(self.moves, self.plan, 0))
        return lt.arrays()


def plan(source, machine=None, policy: str | None = None, jerk: float | None = None, *, strict: bool = False,
         exclude_objects=()) -> Plan:
    """Plan ``source`` whole, in memory: a :class:`Plan` with its MOVE, PLAN and SEGMENT rows.
    ``exclude_objects``: object names cancelled as Klipper's exclude_object runs them.
    For big files prefer :func:`gcodeplan.pipeline.run` with a sink of your own (bounded memory)."""
    machine = as_machine(machine)
    sink = pipeline.Collect(segments=True)
    res = pipeline.run(source, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink],
                       exclude_objects=exclude_objects)
    moves, plan_rows, segs = sink.arrays()
    r = res.reader
    return Plan(moves, plan_rows, segs, np.array(r.limits), list(r.layer_z), list(r.features), r.summary,
                res.policy, res.mode)


def steps(source, machine=None, kinematics=None, policy: str | None = None, jerk: float | None = None, *,
          strict: bool = False, sds_filter: float | None = None,
          ik_search: str = "klipper") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Exact step times of every stepper: ``{name: (times_s float64, dirs int8)}``, times from the
    first move's start (Klipper's step convention: docs/design.md). ``kinematics``: None = the
    machine's, or a :class:`gcodeplan.kinematics.Linear` (any linear machine). ``sds_filter``: the
    step+dir+step filter window (s), e.g. Klipper's 750e-9; None = off. ``ik_search``: a plug-in kinematics'
    motors are stepped by Klipper's own search ("klipper", within ~10 ns of Klipper's steps) or by the step
    engine's guarded search ("exact": about 2x faster, each step within 1 ns of its half-step point; on rotary
    joints up to ~1.3 µs from Klipper's, whose search stops within 1e-9 rad) or from verified polynomial
    stand-ins of the ik ("fit": no ik call per step, 3-8x faster than "klipper"; every fitted step within 1 ns
    of its crossing, pieces near a turning point by the exact search). All steps are kept in memory:
    for big files use ``gcodeplan steps`` (streams to disk)."""
    from .stepper.source import StepSink, rails_from

    machine = as_machine(machine)
    parts: dict[int, list] = {}

    def collect(si, t, d):
        parts.setdefault(si, []).append((t.copy(), d.copy()))

    rails = rails_from(machine, kinematics)
    sink = StepSink(rails, collect, sds_filter_t=sds_filter, machine=machine, ik_search=ik_search)
    pipeline.run(source, machine, policy=policy, jerk=jerk, strict=strict, sinks=[sink])
    out = {}
    for si, rail in enumerate(rails):
        chunks = parts.get(si, [])
        if chunks:
            out[rail.name] = (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]))
        else:
            out[rail.name] = (np.empty(0, np.float64), np.empty(0, np.int8))
    return out


__all__ = ["load_machine", "estimate", "plan", "Plan", "steps"]
