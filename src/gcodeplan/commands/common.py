"""Options and helpers every command that reads G-code shares."""
from __future__ import annotations

import argparse
import math
import os
import sys

from ..errors import GcodeplanError


def add_machine_arguments(p: argparse.ArgumentParser) -> None:
    """--machine / --klipper-config / --flavor / --strict."""
    g = p.add_argument_group("machine")
    src = g.add_mutually_exclusive_group()
    src.add_argument("--machine", metavar="M.toml",
                     help="machine description in gcodeplan's TOML format, or a preset name "
                          "(klipper, marlin, grbl); default: the klipper preset")
    src.add_argument("--klipper-config", metavar="printer.cfg",
                     help="read the machine from a Klipper printer.cfg (G-code then has Klipper's meanings)")
    src.add_argument("--linuxcnc-ini", metavar="mill.ini",
                     help="read the machine from a LinuxCNC .ini ([TRAJ], [AXIS_*], [JOINT_*], [EMCMOT]); "
                          "plans with the linuxcnc policy")
    g.add_argument("--flavor", choices=("marlin", "klipper", "reprap", "grbl", "linuxcnc"),
                   help="G-code dialect, overriding the machine's (G4 P units, M204 meaning, G0 rate)")
    g.add_argument("--firmware", choices=("generic", "grbl-1.1", "marlin-2.1.2", "marlin-bugfix", "klipper",
                                          "linuxcnc"),
                   help="firmware model, overriding the machine's: grbl-1.1 runs grbl's own planner, segment "
                        "generator and step timing, marlin-2.1.2 Marlin 2.1.2.4's planner buffer and stepper "
                        "timing, marlin-bugfix Marlin bugfix-2.1.x's (2024-07-30), klipper and linuxcnc the "
                        "klipper and linuxcnc policies (Klipper's and LinuxCNC 2.9's planners); generic plans "
                        "with the junction policy alone")
    g.add_argument("--strict", action="store_true",
                   help="unknown commands are an error instead of being counted")
    g.add_argument("--no-bounds", action="store_true",
                   help="do not check moves against the machine's travel limits (position_min/position_max)")


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    """--policy and --jerk: how the planner joins moves and shapes their speed."""
    from ..planner.policies import policy_names

    p.add_argument("--policy", metavar="NAME",
                   help=f"junction policy, overriding the machine's ({', '.join(policy_names())}, or one "
                        "registered with gcodeplan.register_policy)")
    p.add_argument("--jerk", type=float, metavar="J",
                   help="plan jerk-limited S-curves with this path jerk limit (mm/s³) instead of trapezoids")
    p.add_argument("--plugin", action="append", default=[], metavar="MODULE|FILE.py",
                   help="import this Python module or file first (repeatable): it may register policies with "
                        "gcodeplan.register_policy, which --policy can then name, and kinematics with "
                        "gcodeplan.kinematics.register, which a machine file's kinematics = \"…\" can then name")


def load_plugins(specs) -> None:
    """Import each ``--plugin``: a module name, or a path to a ``.py`` file."""
    import importlib
    import importlib.util

    for spec in specs or ():
        try:
            if spec.endswith(".py") or os.sep in spec or "/" in spec:
                if not os.path.isfile(spec):
                    raise GcodeplanError(f"--plugin {spec}: no such file")
                name = "gcodeplan_plugin_" + os.path.splitext(os.path.basename(spec))[0]
                mod_spec = importlib.util.spec_from_file_location(name, spec)
                module = importlib.util.module_from_spec(mod_spec)
                sys.modules[name] = module
                mod_spec.loader.exec_module(module)
            else:
                importlib.import_module(spec)
        except GcodeplanError:
            raise
        except Exception as err:  # a plugin is the user's code: say which one failed and how
            raise GcodeplanError(f"--plugin {spec}: {type(err).__name__}: {err}") from None


def check_plan_arguments(args) -> None:
    """Load --plugin modules, then refuse a bad --jerk or an unknown --policy before any file is read."""
    load_plugins(getattr(args, "plugin", None))
    jerk = getattr(args, "jerk", None)
    if jerk is not None and not (jerk > 0 and math.isfinite(jerk)):
        raise GcodeplanError(f"--jerk must be a positive number (mm/s³), got {jerk:g}")
    policy = getattr(args, "policy", None)
    if policy is not None:
        from ..planner.policies import get_policy

        get_policy(policy)


def machine_from_args(args):
    """The machine a command runs with (see :func:`gcodeplan.config.machine_from_args`)."""
    from ..config import machine_from_args as build

    return build(args)     # --no-bounds included


def progress_bar(source, quiet: bool):
    """A progress bar of the work on stderr, only on a terminal, only for runs over a second, only when the
    source's size is known: ``callback(bytes_done)`` takes the input bytes whose moves every sink has
    handled (:class:`gcodeplan.pipeline.WorkBytes`), as ``pipeline.run(progress=...)`` gives them.
    Returns (bar or None, callback or None); close the bar when done (it then leaves no line behind)."""
    if quiet or not sys.stderr.isatty() or not isinstance(source, (str, os.PathLike)) or str(source) == "-":
        return None, None
    try:
        total = os.path.getsize(source)
    except OSError:
        return None, None
    from tqdm import tqdm

    bar = tqdm(total=total, unit="B", unit_scale=True, delay=progress_delay_s(),
               desc=os.path.basename(str(source)), file=sys.stderr, leave=False)
    return bar, (lambda done: bar.update(max(0, min(done, total) - bar.n)))


#: a run shows its progress bar once it has taken this long (s): short runs print no bar at all
PROGRESS_DELAY_S = 1.0


def progress_delay_s() -> float:
    """:data:`PROGRESS_DELAY_S`, or ``GCODEPLAN_PROGRESS_DELAY`` (s) when set: tests show the bar at once."""
    try:
        return max(0.0, float(os.environ.get("GCODEPLAN_PROGRESS_DELAY", PROGRESS_DELAY_S)))
    except ValueError:
        return PROGRESS_DELAY_S
