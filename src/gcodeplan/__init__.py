"""gcodeplan: a motion planner for G-code machines (parse, plan, step, report).

    import gcodeplan as gp
    m = gp.load_machine("klipper")                  # preset, machine .toml, or klipper_config="printer.cfg"
    est = gp.estimate("part.gcode", m)              # est.total_time_s, est.to_json(), est.line_times()
    plan = gp.plan("part.gcode", m)                 # MOVE / PLAN / SEGMENT rows; plan.sample(times)
    th = gp.Toolhead(m); th.gcode("G1 X10 F6000"); th.flush()
    steps = gp.steps("part.gcode", m)               # {stepper: (times_s, dirs)}

Walk-through with runnable examples: docs/api.md. Units everywhere: mm, s, mm/s, mm/s², mm/s³.
Names are imported on first use, so ``import gcodeplan`` itself costs nothing.
"""
from __future__ import annotations

import importlib

__version__ = "0.2.0"

# public name -> (module, attribute); attribute None = the module itself
_EXPORTS = {
    "load_machine": ("gcodeplan.api", "load_machine"),
    "estimate": ("gcodeplan.api", "estimate"),
    "plan": ("gcodeplan.api", "plan"),
    "Plan": ("gcodeplan.api", "Plan"),
    "steps": ("gcodeplan.api", "steps"),
    "Toolhead": ("gcodeplan.toolhead", "Toolhead"),
    "register_policy": ("gcodeplan.planner.policies", "register_policy"),
    "unregister_policy": ("gcodeplan.planner.policies", "unregister_policy"),
    "policy_names": ("gcodeplan.planner.policies", "policy_names"),
    "Machine": ("gcodeplan.machine", "Machine"),
    "Estimate": ("gcodeplan.report.estimate", "Estimate"),
    "GcodeplanError": ("gcodeplan.errors", "GcodeplanError"),
    "kinematics": ("gcodeplan.kinematics", None),
    "pipeline": ("gcodeplan.pipeline", None),
    "profiles": ("gcodeplan.profiles", None),
    "schema": ("gcodeplan.schema", None),
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'gcodeplan' has no attribute {name!r}") from None
    mod = importlib.import_module(module)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
