"""gcodeplan's grbl 1.1 model against grbl 1.1h itself (grbl-sim, lock-step; ../shared/reference/grbl/).

    python tools/compare_grbl.py [NAME ...]

For each reference program (its grbl preprocessing applied, as the README says): the total (time of the last
step) against grbl's, the largest per-line end-time error, and per axis the step count, the largest step-time
error and the share of steps within 1 µs. Reads ../shared; prints a Markdown table.
"""
from __future__ import annotations

import csv
import gzip
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "src"))

import gcodeplan as gp                      # noqa: E402
from gcodeplan.planner import grbl as G     # noqa: E402

SHARED = REPO.parent / "shared"
REF = SHARED / "reference" / "grbl"


def program_text(entry: dict) -> str:
    """The program grbl-sim ran: the file with the README's preprocessing edits (whole lines grbl rejects)."""
    path = SHARED.parent / entry["program"]
    lines = path.read_text().split("\n")
    for edit in entry["preprocessing"]:
        i = edit["line"] - 1
        if lines[i].rstrip("\r") != edit["before"]:
            raise SystemExit(f"{path}:{edit['line']}: preprocessing does not apply")
        lines[i] = edit["after"]
    return "\n".join(lines)


def compare(name: str, entry: dict, machine) -> dict:
    with tempfile.NamedTemporaryFile("w", suffix=".gcode", delete=False) as f:
        f.write(program_text(entry))
    try:
        moves = gp.plan(f.name, machine).moves
    finally:
        Path(f.name).unlink()
    z = np.load(REF / "steps" / f"{name}_steps.npz")
    capacity = max(len(z[f"stepper_{a}"]) for a in "xyz") + 1
    run = G.run(moves, G.GrblSettings.from_machine(machine), steps_capacity=capacity)
    ours: dict[int, float] = {}
    ok = np.isfinite(run.row_end_s)
    for line, t in zip(moves["line"][ok], run.row_end_s[ok]):
        ours[int(line)] = max(ours.get(int(line), -1.0), float(t))
    with gzip.open(REF / "per_line" / f"{name}.per_line_end_time.csv.gz", "rt") as fh:
        rows = list(csv.DictReader(fh))
    line_err = max(abs(ours.get(int(r["source_line"]), np.inf) - float(r["end_time_s"])) for r in rows)
    out = {"name": name, "ref_s": entry["total_time_s"], "ours_s": run.total_s, "line_err_s": line_err,
           "lines": len(rows), "steps": {}}
    for a in "xyz":
        ref_t = z[f"stepper_{a}"]
        t, d = run.steps[f"stepper_{a}"]
        same = len(t) == len(ref_t) and bool(np.array_equal(d, z[f"stepper_{a}_dir"]))
        err = np.abs(t - ref_t) if same and len(t) else np.zeros(0)
        out["steps"][a] = (len(ref_t), len(t), same, float(err.max()) if len(err) else 0.0,
                           float((err <= 1e-6).mean()) if len(err) else 1.0)
    return out


def main(argv: list[str]) -> int:
    if not REF.is_dir():
        print(f"{REF} not found", file=sys.stderr)
        return 2
    times = json.loads((REF / "times.json").read_text())
    machine = gp.load_machine(str(REF / "grbl_settings.txt"))      # its $$ report
    names = argv or list(times)
    print("| program | grbl 1.1h s | gcodeplan grbl-1.1 s | difference | max per-line error | steps equal "
          "| max step error | steps within 1 µs |")
    print("|---|---:|---:|---:|---:|---|---:|---:|")
    for name in names:
        r = compare(name, times[name], machine)
        diff = (r["ours_s"] - r["ref_s"]) / r["ref_s"]
        steps = r["steps"].values()
        equal = all(s[2] for s in steps)
        worst = max(s[3] for s in steps)
        share = min(s[4] for s in steps if s[0]) if any(s[0] for s in steps) else 1.0
        print(f"| {name} | {r['ref_s']:.7f} | {r['ours_s']:.7f} | {diff:+.2e} | {r['line_err_s'] * 1e6:.3f} µs "
              f"| {'yes' if equal else 'NO'} | {worst * 1e6:.3f} µs | {share * 100:.3f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
