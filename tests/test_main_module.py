"""``python -m gcodeplan`` is the ``gcodeplan`` command (a user who has not put the script on PATH)."""
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "gcode_samples" / "prusaslicer25_cube20_marlin2.gcode"


def test_python_dash_m_runs_the_command_with_its_exit_status(tmp_path):
    env_src = str(REPO / "src")
    run = subprocess.run([sys.executable, "-m", "gcodeplan", "estimate", "--json", str(SAMPLE)],
                         capture_output=True, text=True, env={"PYTHONPATH": env_src, "PATH": "/usr/bin:/bin"},
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    import json

    # Klipper's own total for this file on the reference machine (tools/compare_klipper.py; 6 decimals there)
    assert abs(json.loads(run.stdout)["total_time_s"] - 1177.230) < 5e-4
    bad = subprocess.run([sys.executable, "-m", "gcodeplan", "estimate", str(tmp_path / "missing.gcode")],
                         capture_output=True, text=True, env={"PYTHONPATH": env_src, "PATH": "/usr/bin:/bin"},
                         cwd=tmp_path)
    assert bad.returncode != 0 and "missing.gcode" in bad.stderr and "Traceback" not in bad.stderr
