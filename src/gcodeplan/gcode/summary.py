"""What a parsed file contains: counts, distances, filament, the naive time, slicer's own estimate."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from ..schema import KIND_NAMES


def hms(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "-"
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h {m:02d}m {s:02d}s"


def box_text(b: dict[str, list[float]]) -> str:
    """A bounding box {"x": [min, max], ...} (mm) as one line: ``x 0.0…200.0  y …  z … mm``."""
    return "  ".join(f"{a} {lo:.1f}…{hi:.1f}" for a, (lo, hi) in b.items()) + " mm"


def capped_text(count: int, first_line: int | None) -> str:
    """The one note about moves whose requested speed was above the machine's limit."""
    return (f"{count} move{'s' if count != 1 else ''} asked for more than the machine's speed limit and "
            f"{'were' if count != 1 else 'was'} capped to it, as the firmware does (first at line {first_line})")


def clamped_text(count: int, first_line: int | None) -> str:
    """The one note about moves Marlin's software endstops clamped (Marlin's apply_motion_limits)."""
    return (f"{count} move{'s' if count != 1 else ''} (or arc chord{'s' if count != 1 else ''}) went past the software "
            f"endstops and {'were' if count != 1 else 'was'} clamped to them, as Marlin does (first at line "
            f"{first_line})")


@dataclass
class ParseSummary:
    file: str = ""
    lines: int = 0
    rows: int = 0                      # MOVE rows of any kind (incl. dwell / wait rows)
    moves: int = 0                     # travel + print + extrude-only rows (non-zero length)
    moves_by_kind: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KIND_NAMES})
    layer_count: int = 0
    header_layer_count: int | None = None   # Cura ;LAYER_COUNT:
    travel_mm: float = 0.0             # XYZ path length of non-extruding moves
    print_mm: float = 0.0              # XYZ path length of extruding moves
    filament_mm: float = 0.0           # net E change (after M221)
    retracts: int = 0
    naive_time_s: float = 0.0          # Σ move_d / feed_v (rapids at the machine's rapid rate) + G4 dwells
    dwell_s: float = 0.0               # G4
    wait_s: float = 0.0                # M109/M190 heat waits, homing (machine settings)
    waits: dict[str, int] = field(default_factory=dict)
    arcs: int = 0
    arc_chords: int = 0
    canned_cycles: int = 0
    spindle_commands: int = 0
    tool_changes: int = 0
    unknown_commands: dict[str, int] = field(default_factory=dict)
    ignored_commands: dict[str, int] = field(default_factory=dict)   # known, but the dialect ignores them
    skipped_lines: int = 0             # lines with an unexpanded slicer placeholder
    events: list[tuple[int, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    warning_count: int = 0
    slicer_estimate_s: float | None = None
    features: list[str] = field(default_factory=list)
    limits_rows: int = 1
    bounds_mm: dict[str, list[float]] | None = None   # {"x": [min, max], ...} of move end points
    # bounding boxes of motion (mm, start and end points), printing and travel moves apart (gcode/bounds.py)
    print_bounds_mm: dict[str, list[float]] | None = None
    travel_bounds_mm: dict[str, list[float]] | None = None
    speed_capped_moves: int = 0                    # moves whose feed was above the speed limit: capped
    speed_capped_first_line: int | None = None
    soft_clamped_moves: int = 0                    # targets clamped to Marlin's software endstops
    soft_clamped_first_line: int | None = None
    # what the file says it is (gcode/dialect.py): {"kind": "printer"|"cnc", "program", "evidence", "flavor" (the
    # flavor its G-code was read with), "switched" (the default preset's flavor was changed for it),
    # "volumetric_filament_mm" (UltiGCode), "warning"}; None when the file names no slicer/CAM program
    dialect: dict | None = None

    def to_json(self) -> dict:
        d = asdict(self)
        d["events"] = [list(e) for e in self.events]
        return d

    def text(self) -> str:
        from .dialect import note_text

        lines = [f"file            {self.file}",
                 f"lines           {self.lines}",
                 f"moves           {self.moves}  (" + ", ".join(f"{k} {v}" for k, v in self.moves_by_kind.items())
                 + ")",
                 f"layers          {self.layer_count}"
                 + (f"  (header says {self.header_layer_count})" if self.header_layer_count is not None else ""),
                 f"travel          {self.travel_mm:.1f} mm",
                 f"print           {self.print_mm:.1f} mm",
                 f"filament        {self.filament_mm:.1f} mm",
                 f"retractions     {self.retracts}",
                 f"naive time      {hms(self.naive_time_s)}  ({self.naive_time_s:.1f} s: length / feed, no "
                 f"acceleration)",
                 ]
        if self.dialect:
            lines.insert(1, f"dialect         {note_text(self.dialect)}")
        for what, b in (("print box", self.print_bounds_mm), ("travel box", self.travel_bounds_mm)):
            if b:
                lines.append(f"{what:<16}{box_text(b)}")
        if self.speed_capped_moves:
            lines.append(f"speed capped    {capped_text(self.speed_capped_moves, self.speed_capped_first_line)}")
        if self.soft_clamped_moves:
            lines.append(f"clamped         {clamped_text(self.soft_clamped_moves, self.soft_clamped_first_line)}")
        if self.dwell_s:
            lines.append(f"dwells          {self.dwell_s:.3f} s")
        if self.waits:
            lines.append("waits           " + ", ".join(f"{k} {v}" for k, v in sorted(self.waits.items())))
        if self.arcs:
            lines.append(f"arcs            {self.arcs} ({self.arc_chords} chords)")
        if self.canned_cycles:
            lines.append(f"canned cycles   {self.canned_cycles}")
        if self.slicer_estimate_s is not None:
            lines.append(f"slicer estimate {hms(self.slicer_estimate_s)}  ({self.slicer_estimate_s:.0f} s)")
        if self.unknown_commands:
            lines.append("unknown         " + ", ".join(f"{k} ×{v}" for k, v in
                                                        sorted(self.unknown_commands.items())))
        if self.ignored_commands:
            lines.append("ignored         " + ", ".join(f"{k} ×{v}" for k, v in
                                                        sorted(self.ignored_commands.items())))
        if self.skipped_lines:
            lines.append(f"skipped lines   {self.skipped_lines}")
        if self.warning_count:
            lines.append(f"warnings        {self.warning_count}")
            lines.extend("  " + w for w in self.warnings[:10])
        return "\n".join(lines)
