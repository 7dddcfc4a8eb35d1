"""The code's structure: no import cycles between the modules of src/gcodeplan (tools/import_cycles.py)."""
from __future__ import annotations

import importlib.util
import sys

import pytest

from conftest import REPO


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


ic = _tool("import_cycles")

# Cycles whose fix lives in files another change owns: remove an entry once that change is merged (none now).
KNOWN: list[list[str]] = []


@pytest.mark.parametrize("module_level", [False, True], ids=["all-imports", "module-level"])
def test_no_import_cycles_in_the_package(module_level):
    """Function-level imports count too (``all-imports``): they hide a cycle from start-up, not from the design."""
    graph = ic.import_graph(module_level=module_level)
    assert len(graph) > 80 and "gcodeplan.planner.stream" in graph
    found = [c for c in ic.cycles(graph) if c not in KNOWN]
    assert found == [], [" -> ".join(ic.one_cycle(graph, c)) for c in found]


def _package(tmp_path, files: dict[str, str]):
    for rel, text in files.items():
        p = tmp_path / "pkg" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def test_the_checker_finds_a_function_level_cycle(tmp_path):
    src = _package(tmp_path, {
        "__init__.py": "",
        "a.py": "from . import b\n",
        "b.py": "def f():\n    from .a import x\n",
        "sub/__init__.py": "from .leaf import y\n",
        "sub/leaf.py": "from .. import a\n",          # leaf -> a -> b: no cycle back to sub
    })
    everything = ic.import_graph(src=src, package="pkg")
    assert everything["pkg.a"] == {"pkg.b": 1} and everything["pkg.b"] == {"pkg.a": 2}
    assert ic.cycles(everything) == [["pkg.a", "pkg.b"]]
    assert ic.one_cycle(everything, ["pkg.a", "pkg.b"]) == ["pkg.a", "pkg.b", "pkg.a"]
    assert ic.cycles(ic.import_graph(module_level=True, src=src, package="pkg")) == []


def test_the_checker_follows_a_package_reexport_and_skips_type_checking(tmp_path):
    src = _package(tmp_path, {
        "__init__.py": "",
        "k/__init__.py": "from .lin import Lin\nfrom typing import TYPE_CHECKING\n"
                         "if TYPE_CHECKING:\n    from ..m import M\n",
        "k/lin.py": "from . import Rail\n",       # the package itself: k -> k.lin -> k
        "m.py": "import pkg.k.lin\n",
    })
    graph = ic.import_graph(src=src, package="pkg")
    assert "pkg.m" not in graph["pkg.k"]
    assert graph["pkg.m"] == {"pkg.k.lin": 1}
    assert ic.cycles(graph) == [["pkg.k", "pkg.k.lin"]]


# ----------------------------------------------------------------------------- units of the schema's fields
def _schema_fields():
    """(dtype name, field, line, comment) for every field of the dtypes in schema.py, from its source."""
    import ast
    import io
    import tokenize

    path = REPO / "src" / "gcodeplan" / "schema.py"
    text = path.read_text(encoding="utf-8")
    comments = {tok.start[0]: tok.string.lstrip("#").strip()
                for tok in tokenize.generate_tokens(io.StringIO(text).readline) if tok.type == tokenize.COMMENT}
    out = []
    for node in ast.walk(ast.parse(text)):
        if not (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)
                and getattr(node.value.func, "attr", "") == "dtype"):
            continue
        for elt in node.value.args[0].elts:
            name = elt.elts[0].value
            out.append((node.targets[0].id, name, elt.lineno, comments.get(elt.lineno)))
    return out


def _leading_units(comment: str, words) -> list[str]:
    """The units a comment starts with: ``"mm/s, mm/s²: ..."`` -> ["mm/s", "mm/s²"]; ``"s, start"`` -> ["s"]."""
    out = []
    for tok in comment.split():
        word = tok.rstrip(",:")
        if word not in words:
            break
        out.append(word)
        if not tok.endswith(","):
            break
    return out


def test_every_schema_field_declares_its_unit():
    """By its name's suffix (schema.UNIT_SUFFIXES) or first in its comment; where both speak they agree."""
    from gcodeplan import schema

    fields = _schema_fields()
    dtypes = {"MOVE_DTYPE": schema.MOVE_DTYPE, "LIMITS_DTYPE": schema.LIMITS_DTYPE,
              "PLAN_DTYPE": schema.PLAN_DTYPE, "SEGMENT_DTYPE": schema.SEGMENT_DTYPE}
    for dname, dtype in dtypes.items():     # the source walk saw every field of every dtype
        assert [f[1] for f in fields if f[0] == dname] == list(dtype.names)
    per_line: dict[int, list[str]] = {}
    for _, name, line, _ in fields:
        per_line.setdefault(line, []).append(name)
    words = set(schema.UNITS) | set(schema.UNITLESS)
    bad = []
    for dname, name, line, comment in fields:
        by_name = schema.unit_of_name(name)
        said = _leading_units(comment or "", words)
        same_line = per_line[line]
        if len(said) == len(same_line) > 1:
            said = [said[same_line.index(name)]]
        if len(said) > 1:
            bad.append(f"{dname}.{name} (line {line}): {len(said)} units for {len(same_line)} fields")
        elif by_name is None and not said:
            bad.append(f"{dname}.{name} (line {line}): no unit suffix and no unit first in its comment")
        elif by_name is not None and said and said[0] in schema.UNITS and said[0] != by_name:
            bad.append(f"{dname}.{name} (line {line}): the name says {by_name}, the comment {said[0]}")
    assert bad == []


def test_unit_of_name_reads_klipper_style_suffixes():
    from gcodeplan.schema import unit_of_name

    assert [unit_of_name(n) for n in ("move_d", "cruise_v", "junction_v2", "accel_t", "max_a", "delta_slow_xy2",
                                      "accel", "decel", "max_jerk", "jerk_x", "axis_v_x", "t_start")] == [
        "mm", "mm/s", "mm²/s²", "s", "mm/s²", "mm²", "mm/s²", "mm/s²", "mm/s³", None, None, None]
    assert _leading_units("mm/s, mm/s²: Klipper's", {"mm/s", "mm/s²"}) == ["mm/s", "mm/s²"]
    assert _leading_units("s, absolute start", {"s"}) == ["s"]


# ----------------------------------------------------------------------------- docs/design.md's code flow
def _code_flow_section() -> str:
    text = (REPO / "docs" / "design.md").read_text(encoding="utf-8")
    start = text.index("## The code flow of one move")
    return text[start:text.index("\n## ", start + 1)]


def _resolve(dotted: str):
    """``gcode.reader.GcodeReader.batches`` -> the object, importing the longest module prefix of gcodeplan."""
    import importlib

    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module("gcodeplan." + ".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for name in parts[k:]:
            obj = getattr(obj, name)        # AttributeError: the doc names something that is not there
        return obj
    raise ModuleNotFoundError(dotted)


def test_design_code_flow_names_only_real_functions():
    import re

    section = _code_flow_section()
    assert section.startswith("## The code flow of one move") and "docs/Code_Overview.md" in section
    names = sorted(set(re.findall(r"`([a-z_]+(?:\.[A-Za-z_][A-Za-z_0-9]*)+)`", section)))
    names = [n for n in names if not n.endswith((".py", ".md"))]
    assert len(names) > 40
    missing = []
    for n in names:
        try:
            _resolve(n)
        except (ImportError, AttributeError):
            missing.append(n)
    assert missing == []
    # in the order data flows: reader, scanner, planner, segments, sinks
    at = [section.index(f"`{n}`") for n in ("gcode.reader.GcodeReader.batches", "gcode.scan.scan_chunk",
                                             "planner.stream.StreamPlanner.feed", "planner.segments.to_segments",
                                             "stepper.kernel.gen_steps")]
    assert at == sorted(at)


def test_resolve_refuses_a_name_that_is_not_there():
    with pytest.raises(AttributeError):
        _resolve("planner.stream.StreamPlanner.no_such_method")
    with pytest.raises(ModuleNotFoundError):
        _resolve("no_such_module.f")


# ----------------------------------------------------------------------------- planning modes
# Modes still reading the planner's private fields (none now: grbl's and Marlin's use sp.pending_moves, sp.clock)
MODES_NOT_CONVERTED: dict[str, set[str]] = {}


def _private_planner_reads(path) -> set[str]:
    """Private attributes read through a mode's planner (``sp._x`` or ``self.sp._x``) in one file."""
    import ast

    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = node.value
            if (isinstance(owner, ast.Name) and owner.id == "sp") or (
                    isinstance(owner, ast.Attribute) and owner.attr == "sp"):
                out.add(node.attr)
    return out


def test_planning_modes_use_the_planner_interface():
    """The modes reach the StreamPlanner only through its mode interface (planner/stream.py, class _Mode)."""
    from gcodeplan.planner.stream import StreamPlanner

    for name in ("pending_moves", "pending_prep", "clock", "policy_code", "jerk", "stop_pending",
                 "prepare_chunk", "check_same_jerk"):
        assert hasattr(StreamPlanner, name), name
    src = REPO / "src" / "gcodeplan"
    for rel in ("planner/stream.py", "planner/linuxcnc.py", "planner/grbl.py", "planner/marlin.py"):
        assert _private_planner_reads(src / rel) <= MODES_NOT_CONVERTED.get(rel, set()), rel


def test_private_planner_reads_sees_both_spellings(tmp_path):
    p = tmp_path / "m.py"
    p.write_text("def plan(self):\n    sp = self.sp\n    return sp._moves, self.sp._clock, sp.clock, sp.__class__\n")
    assert _private_planner_reads(p) == {"_moves", "_clock"}
