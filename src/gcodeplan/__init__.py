"""gcodeplan: a motion planner for G-code machines (parse, plan, step, report)."""
__version__ = "0.1.0"
