"""numba's disk cache of a kernel must follow the kernel's dependencies, not only its own file.

numba stamps a cached kernel with its defining file alone; a kernel that inlines a function, calls a kernel
or reads a constant of another module kept loading its old machine code after that module was edited.
``_jit`` stamps a kernel with every module it depends on (``_jit._dependency_stamp``). Each test builds a small
package of its own in a temporary directory, with its own numba cache, and runs it in fresh processes (what a
developer does between two edits); no gcodeplan kernel is compiled.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

# the package: one kernel module per way of depending on another module, plus an unrelated module
PACKAGE = {
    "__init__.py": "",
    "dep_inline.py": """
        from gcodeplan._jit import njit

        @njit(cache=True, inline="always")
        def bump(x):
            return x + 1.0
        """,
    "dep_call.py": """
        from gcodeplan._jit import njit

        @njit(cache=True)
        def scale(x):
            return x * 10.0
        """,
    "dep_const.py": """
        OFFSET_MM = 100.0
        """,
    "k_inline.py": """
        from gcodeplan._jit import njit
        from .dep_inline import bump

        @njit(cache=True)
        def kernel(x):
            return bump(x)
        """,
    "k_call.py": """
        from gcodeplan._jit import njit
        from . import dep_call

        @njit(cache=True)
        def kernel(x):
            return dep_call.scale(x)
        """,
    "k_const.py": """
        from gcodeplan._jit import njit
        from .dep_const import OFFSET_MM as OFFSET

        @njit(cache=True)
        def kernel(x):
            return x + OFFSET
        """,
    "unrelated.py": """
        from gcodeplan._jit import njit

        @njit(cache=True)
        def other(x):
            return x - 1.0
        """,
}
KINDS = ("inline", "call", "const")
EDITS = {   # kind -> (file, old, new): the new source gives each kernel of 1.0 another result
    "inline": ("dep_inline.py", "x + 1.0", "x + 2.0"),
    "call": ("dep_call.py", "x * 10.0", "x * 20.0"),
    "const": ("dep_const.py", "100.0", "300.0"),
    "unrelated": ("unrelated.py", "x - 1.0", "x - 2.0"),
    "own": ("k_inline.py", "return bump(x)", "return bump(x) + 0.5"),
}
BEFORE = {"inline": 2.0, "call": 10.0, "const": 101.0, "unrelated": 0.0}   # hand-worked for x = 1.0
AFTER = {"inline": 3.0, "call": 20.0, "const": 301.0, "unrelated": -1.0}

_CHILD = """
import json, sys
import importlib
from gcodeplan import _jit
out = {}
for kind, (mod, name) in {"inline": ("k_inline", "kernel"), "call": ("k_call", "kernel"),
                          "const": ("k_const", "kernel"), "unrelated": ("unrelated", "other")}.items():
    k = getattr(importlib.import_module("tpkg." + mod), name)
    value = k(1.0)
    stats = _jit.compiled(k).stats
    out[kind] = [value, sum(stats.cache_hits.values()), sum(stats.cache_misses.values())]
print(json.dumps(out))
"""


def _write_package(root: Path) -> Path:
    pkg = root / "tpkg"
    pkg.mkdir()
    for name, text in PACKAGE.items():
        (pkg / name).write_text(textwrap.dedent(text))
    return pkg


def _edit(pkg: Path, what: str) -> None:
    """Change a module's source as an editor does: new text, and an mtime later than the cache's."""
    name, old, new = EDITS[what]
    p = pkg / name
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new))
    st = p.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))


def _run(root: Path, env_extra: dict | None = None) -> dict:
    """{kind: (value, cache hits, cache misses)} of one fresh process."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["NUMBA_CACHE_DIR"] = str(root / "numba_cache")
    env["PYTHONPATH"] = os.pathsep.join([str(SRC), str(root)])
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.update(env_extra or {})
    r = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, env=env, cwd=root,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return {k: tuple(v) for k, v in json.loads(r.stdout.strip().splitlines()[-1]).items()}


def _values(res: dict) -> dict:
    return {k: v[0] for k, v in res.items()}


def _loaded(res: dict) -> set:
    """The kernels this process loaded from numba's cache without compiling them."""
    return {k for k, (_, hits, misses) in res.items() if hits == 1 and misses == 0}


@pytest.mark.parametrize("kind", KINDS)
def test_editing_a_dependency_recompiles_only_the_kernels_that_use_it(tmp_path, kind):
    pkg = _write_package(tmp_path)
    first = _run(tmp_path)
    assert _values(first) == BEFORE
    assert _loaded(first) == set()                   # an empty cache: everything compiled
    _edit(pkg, kind)
    second = _run(tmp_path)
    assert _values(second) == {**BEFORE, kind: AFTER[kind]}
    # the edited module's user compiled again; the rest came from the cache
    assert _loaded(second) == set(BEFORE) - {kind}


def test_an_unchanged_tree_loads_every_kernel_from_the_cache(tmp_path):
    pkg = _write_package(tmp_path)
    _run(tmp_path)
    again = _run(tmp_path)
    assert _values(again) == BEFORE and _loaded(again) == set(BEFORE)
    # a new mtime on unchanged text (a checkout, a copy) still loads: stamps are of content, as numba's own
    for p in pkg.glob("*.py"):
        st = p.stat()
        os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 7_000_000_000))
    touched = _run(tmp_path)
    assert _values(touched) == BEFORE and _loaded(touched) == set(BEFORE)


def test_the_kernels_own_file_and_unrelated_files_as_before(tmp_path):
    pkg = _write_package(tmp_path)
    _run(tmp_path)
    _edit(pkg, "unrelated")
    _edit(pkg, "own")
    res = _run(tmp_path)
    assert _values(res) == {**BEFORE, "inline": 1.0 + 1.0 + 0.5, "unrelated": AFTER["unrelated"]}
    assert _loaded(res) == {"call", "const"}


def test_stamps_follow_dependencies_in_numbas_fallback_cache_directory(tmp_path):
    """NUMBA_CACHE_DIR unusable and the package's __pycache__ unwritable: numba falls back to the user-wide
    cache directory, and the dependency stamp comes along."""
    pkg = _write_package(tmp_path)
    (tmp_path / "not_a_dir").write_text("")
    (pkg / "__pycache__").write_text("")             # a file: numba cannot make its cache directory there
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "not_a_dir" / "cache"), "XDG_CACHE_HOME": str(tmp_path / "xdg"),
           "HOME": str(tmp_path)}
    first = _run(tmp_path, env)
    assert _values(first) == BEFORE
    assert list((tmp_path / "xdg").rglob("*.nbi"))   # the fallback directory holds the cache
    _edit(pkg, "inline")
    second = _run(tmp_path, env)
    assert _values(second) == {**BEFORE, "inline": AFTER["inline"]}
    assert _loaded(second) == set(BEFORE) - {"inline"}
