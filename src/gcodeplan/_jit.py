"""Kernels that numba compiles on first use, or that Python runs as written for tiny inputs.

Every hot loop of gcodeplan is a ``@njit(cache=True)`` kernel (this module's :func:`njit`, same options as
``numba.njit``). Importing numba and setting up its compiler costs 0.35–0.45 s of CPU even when every kernel
comes from numba's cache (``python tools/bench.py startup`` prints that floor) — longer than planning a
whole 5 MB file. So nothing imports numba at import time:

* By default the first kernel call imports numba (:func:`activate`), makes every kernel a numba dispatcher
  and rebinds the kernels in gcodeplan's modules, so later calls go straight to compiled code.
* Inside :func:`interpreted` (the pipeline uses it for inputs of at most :data:`SMALL_INPUT_BYTES`), a
  kernel runs its own Python source (``py_func``) on the same arrays: the same statements in the same order,
  so the same IEEE results (``tests/test_jit.py`` compares both on every sample and on fuzzed programs).
  Structured arrays are viewed so that ``row.field`` works as in numba, integers narrower than 64 bits are
  widened as numba widens them, and the scalars a kernel returns are made Python scalars, as numba returns
  them.

Where Python and numba differ — Python raises on ``1.0 / 0.0``, ``math.sqrt(-1.0)`` or ``int(nan)`` where
numba returns inf/nan/garbage, a kernel may use something only numba offers — the outermost interpreted
kernel call restores its array arguments from a copy taken before the call and runs the compiled kernel
instead; so does a run that has interpreted for :data:`INTERPRET_BUDGET_S` (checked at every kernel call).
A wrong answer cannot come from the interpreted path, only a slower start.

numba's disk cache stamps a kernel with its own file only; gcodeplan's kernels are stamped with every module
they depend on (inlined functions, called kernels, imported constants, transitively), so an edit anywhere
recompiles exactly the kernels that can see it (:func:`_install_dependency_stamps`, design.md section 15).
"""
from __future__ import annotations

import sys
import threading
from contextlib import contextmanager
from time import perf_counter
from types import FunctionType, ModuleType

import numpy as np

#: inputs up to this many bytes run interpreted (the pipeline decides; about 500 G1 lines). Interpreting costs
#: 8–14 µs per byte of G-code here (0.1–0.2 s for 16 KB), compiled kernels the 0.35–0.45 s numba start-up once:
#: break-even is near 32 KB, and past :data:`INTERPRET_BUDGET_S` a run switches to compiled kernels anyway.
SMALL_INPUT_BYTES = 16384

_KERNELS: list["Kernel"] = []
_numba = None               # the numba module once :func:`activate` ran
_interpret_depth = 0        # > 0 inside :func:`interpreted`
_this_thread = threading.local()   # .inside: an interpreted kernel runs in this thread (nested calls skip the
                                   # copy); .t0: perf_counter() at the start of that outermost call
#: (kernel, reason) of the first interpreted calls that fell back to numba in this process (diagnostics, tests)
fallbacks: list[tuple[str, str]] = []
#: s of interpreting after which kernels go compiled: a small input can still ask for much work (a huge arc
#: in tiny chords). About numba's own start-up here, the rent-or-buy choice: a run never takes more than
#: about twice what the better of the two ways would have taken
INTERPRET_BUDGET_S = 0.4
_interpreted_s = 0.0        # s spent in outermost interpreted calls so far (all threads)
#: a kernel given an array longer than this runs compiled: its loop is over that array (chords, steps,
#: samples), and one interpreted call cannot be stopped at the budget halfway (a tiny file's huge arc)
MAX_INTERPRETED_ELEMENTS = 65_536
#: set by the ``gcodeplan`` command for its own process (never by the library, whose caller owns numba's set-up
#: and the garbage collector): cached kernels load without numba's registry refresh and numba's objects go to
#: the permanent GC generation (see :func:`activate`)
command_process = False


class Kernel:
    """A function numba compiles on first use (see the module docstring). Call it like the function.

    ``py_func`` is the Python function; ``dispatcher`` the numba dispatcher once numba is active.
    """


    def __init__(self, py_func, options: dict):
        self.py_func = py_func
        self.options = options
        self.dispatcher = None
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__module__ = py_func.__module__
        self.__doc__ = py_func.__doc__
        self.__wrapped__ = py_func

    def __repr__(self) -> str:
        return f"<gcodeplan kernel {self.__module__}.{self.__qualname__}>"

    def __reduce__(self):
        # pickled by name, as a function is: the receiving process finds its own kernel (or dispatcher)
        return (_kernel_named, (self.__module__, self.__qualname__))

    def __call__(self, *args):
        d = self.dispatcher
        if d is not None:
            return d(*args)
        if _interpret_depth and _numba is None and _interpreted_s <= INTERPRET_BUDGET_S:
            return self._interpret(args)
        activate()
        return self.dispatcher(*args)

    def _interpret(self, args):
        global _interpreted_s
        here = _this_thread
        too_long = any(isinstance(a, np.ndarray) and a.size > MAX_INTERPRETED_ELEMENTS for a in args)
        if getattr(here, "inside", False):       # the outermost call restores and falls back for us
            if too_long:
                raise _Diverges(_TOO_LONG)
            if _interpreted_s + (perf_counter() - here.t0) > INTERPRET_BUDGET_S:
                raise _Diverges("interpreting took too long")
            return _run_python(self.py_func, args)
        if too_long:
            return self._compiled_instead(args, _TOO_LONG)
        saved = [(a, a.copy()) for a in args if isinstance(a, np.ndarray)]
        here.inside = True
        t0 = here.t0 = perf_counter()
        reason = None
        try:
            with np.errstate(all="ignore"):
                out = _run_python(self.py_func, args)
        except Exception as err:                 # a Python/numba difference: run the compiled kernel instead
            reason = repr(err)[:200]
        finally:                                 # (KeyboardInterrupt and SystemExit just leave)
            here.inside = False
            _interpreted_s += perf_counter() - t0
        if reason is None:
            return _as_numba_returns(out)
        for a, copy in saved:
            if a.flags.writeable:
                a[...] = copy
        return self._compiled_instead(args, reason)

    def _compiled_instead(self, args, reason: str):
        """Run the compiled kernel (importing numba if needed), noting why in :data:`fallbacks`."""
        if len(fallbacks) < 100:
            fallbacks.append((self.__qualname__, reason))
        activate()
        return self.dispatcher(*args)


_TOO_LONG = "an array too long to interpret"


class _Diverges(Exception):
    """Python would not compute what numba computes here (aliased widened arrays, a view of one returned)."""


_WIDE: dict = {}


def _wide_dtype(dt: np.dtype):
    """The dtype with every integer narrower than 64 bits made int64 (None when there is none).

    numba computes with such integers as int64 (``buf[i] - 48`` on uint8 is -48..207), NumPy's scalars stay
    narrow and wrap: the interpreted kernel sees widened copies, written back afterwards with numba's
    truncating stores."""
    try:
        return _WIDE[dt]
    except KeyError:
        pass
    wide = None
    if dt.names is None:
        if dt.kind in "iu" and dt.itemsize < 8:
            wide = np.dtype(np.int64)
    else:
        fields = []
        for name in dt.names:
            ft = dt.fields[name][0]
            if ft.kind in "iu" and ft.itemsize < 8 and ft.shape == ():
                fields.append((name, np.int64))
                wide = True
            else:
                fields.append((name, ft))
        wide = np.dtype(fields) if wide else None
    _WIDE[dt] = wide
    return wide


class _Row:
    """One row of a structured array as numba shows it: ``row.field`` reads and writes the array (NumPy's
    own record type would answer ``row.flags`` with its array flags, not the MOVE field)."""

    __slots__ = ("_v",)

    def __init__(self, v):
        object.__setattr__(self, "_v", v)

    def __getattr__(self, name):
        try:
            return self._v[name]
        except (ValueError, KeyError, IndexError):
            raise AttributeError(name) from None

    def __setattr__(self, name, value):
        self._v[name] = value

    def __getitem__(self, name):
        return self._v[name]

    def __setitem__(self, name, value):
        self._v[name] = value


class _Rows(np.ndarray):
    """A structured array whose rows are :class:`_Row` (numba's record semantics, for interpreted kernels)."""

    def __getitem__(self, idx):
        out = super().__getitem__(idx)
        if isinstance(out, np.void):
            return _Row(out)
        return out

    def __setitem__(self, idx, value):
        if isinstance(value, _Row):
            value = value._v
        super().__setitem__(idx, value)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]


class _LibmMath:
    """``math`` as numba computes it: numba calls the C library's ``hypot``, CPython's math.hypot has its
    own algorithm (they differ in the last bit of about 1 result in 160)."""

    def __init__(self):
        import ctypes
        import ctypes.util
        import math

        self.__dict__.update({k: getattr(math, k) for k in dir(math) if not k.startswith("__")})
        hypot = ctypes.CDLL(ctypes.util.find_library("m")).hypot
        hypot.restype = ctypes.c_double
        hypot.argtypes = (ctypes.c_double, ctypes.c_double)
        self.hypot = hypot


class _LibmNumpy:
    """``numpy`` as numba computes its scalar maths: numba's np.cbrt is the C library's cbrt, NumPy's own
    (vectorised) cbrt differs in the last bit of about 1 result in 2."""

    def __init__(self):
        import math

        self._cbrt = math.cbrt

    def __getattr__(self, name):
        return getattr(np, name)

    def cbrt(self, x):
        if isinstance(x, np.ndarray):
            raise _Diverges("np.cbrt of an array")
        return self._cbrt(x)


_PYTHON_FUNCS: dict = {}


def _as_numba_computes(py_func):
    """``py_func`` with ``math`` and ``np`` in its globals replaced by :class:`_LibmMath` / :class:`_LibmNumpy`
    (a copy of its module's globals, made once per kernel)."""
    try:
        return _PYTHON_FUNCS[py_func]
    except KeyError:
        pass
    import types

    if "libm" not in _PYTHON_FUNCS:
        _PYTHON_FUNCS["libm"] = (_LibmMath(), _LibmNumpy())
    libm_math, libm_np = _PYTHON_FUNCS["libm"]
    g = dict(py_func.__globals__)
    for name, val in list(g.items()):
        if val is np:
            g[name] = libm_np
        elif getattr(val, "__name__", None) == "math" and isinstance(val, types.ModuleType):
            g[name] = libm_math
    fn = types.FunctionType(py_func.__code__, g, py_func.__name__, py_func.__defaults__, py_func.__closure__)
    fn.__kwdefaults__ = py_func.__kwdefaults__
    _PYTHON_FUNCS[py_func] = fn
    return fn


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """True when ``a`` and ``b`` share a byte (two fields of one structured array do not); True when that is
    too hard to tell."""
    if not np.may_share_memory(a, b):
        return False
    try:
        return bool(np.shares_memory(a, b, max_work=10_000))
    except np.exceptions.TooHardError:
        return True


def _run_python(py_func, args):
    """``py_func(*args)`` with numba's view of the arrays: narrow integers widened (copied in and out) and
    structured arrays whose rows read and write fields as attributes (``row.field`` as in numba)."""
    pargs = []
    back = []
    for a in args:
        if isinstance(a, np.ndarray):
            a = a.view(np.ndarray)
            wide = _wide_dtype(a.dtype)
            if wide is not None:
                w = np.empty(a.shape, wide)
                if a.dtype.names is None:
                    w[...] = a
                else:
                    for name in a.dtype.names:
                        w[name] = a[name]
                back.append((a, w))
                a = w
            if a.dtype.names is not None:
                a = a.view(_Rows)
        pargs.append(a)
    if back:
        arrays = [a for a in args if isinstance(a, np.ndarray)]
        for a, _ in back:
            if sum(1 for b in arrays if _overlap(a, b)) > 1:
                raise _Diverges("widened array aliased by another argument")
    out = _as_numba_computes(py_func)(*pargs)
    for a, w in back:
        if a.flags.writeable:
            if a.dtype.names is None:
                a[...] = w
            else:
                for name in a.dtype.names:
                    a[name] = w[name]
        for o in (out if isinstance(out, tuple) else (out,)):
            if isinstance(o, np.ndarray) and np.may_share_memory(o, w):
                raise _Diverges("returns a view of a widened array")
    return out


def _kernel_named(module: str, qualname: str):
    """The kernel ``module.qualname`` in this process (a :class:`Kernel`, or its dispatcher once numba is active)."""
    import importlib

    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _as_numba_returns(out):
    """What numba would hand back: Python scalars for NumPy scalars, plain arrays, tuples element-wise."""
    if isinstance(out, tuple):
        return tuple(_as_numba_returns(x) for x in out)
    if isinstance(out, np.ndarray):
        return out.view(np.ndarray) if type(out) is not np.ndarray else out
    if isinstance(out, _Row):
        return out._v
    if isinstance(out, np.generic):
        return out.item()
    return out


def njit(*args, **options):
    """``numba.njit`` for gcodeplan's kernels, compiled on first use (module docstring).

    ``@njit(cache=True, ...)`` or ``@njit``; options go to ``numba.njit`` unchanged.
    """
    bare = bool(args) and callable(args[0]) and len(args) == 1 and not options
    options.setdefault("nogil", True)    # kernels touch no Python object: other threads run meanwhile

    def wrap(fn):
        _STAMPED_PACKAGES.add((getattr(fn, "__module__", None) or "").partition(".")[0])
        if _numba is not None:           # a module imported after activation
            dispatcher = _numba.njit(**options)(fn)
            if command_process:
                _load_without_refresh(dispatcher)
            return dispatcher
        k = Kernel(fn, options)
        _KERNELS.append(k)
        return k

    if bare:
        return wrap(args[0])
    return wrap


def is_kernel(fn) -> bool:
    """True for a gcodeplan kernel or a numba dispatcher (anything a kernel can take as a function)."""
    if isinstance(fn, Kernel):
        return True
    return _numba is not None and isinstance(fn, _numba.core.registry.CPUDispatcher)


def compiled(fn):
    """The numba dispatcher of ``fn`` (a :class:`Kernel` or a dispatcher), importing numba if needed."""
    if isinstance(fn, Kernel):
        activate()
        return fn.dispatcher
    return fn


def numba_module():
    """The numba module (imported and set up on the first call, see :func:`activate`)."""
    activate()
    return _numba


def activate() -> None:
    """Import numba and make every kernel a compiled numba dispatcher (idempotent).

    When :data:`command_process` is set (the ``gcodeplan`` command sets it for its own process), kernels
    load their cached machine code without numba's registry refresh (:func:`_load_without_refresh`): that
    refresh imports ~250 modules, among them numba's BLAS probe, which imports SciPy's linalg when SciPy is
    installed. It cost 0.14–0.3 s of a 50 MB estimate's 1.1–1.3 s here (``python tools/bench.py startup``).
    A kernel not in the cache still compiles, with the refresh numba's compiler makes itself. In that
    process numba's large object graph, alive until exit anyway, then goes to the permanent GC generation,
    which spares later collections and the final one from walking it (1.37 s -> 0.86 s on ``gcodeplan
    parse`` of the 1.85 M-line file when it was measured).
    """
    global _numba
    if _numba is not None:
        return
    import gc

    collecting = gc.isenabled()
    if command_process:
        # no cycle collection while numba's ~100,000 long-lived objects are made (20-30 ms of collections
        # otherwise): they go to the permanent generation at the end
        gc.disable()
    try:
        _import_numba()
        _install_dependency_stamps()
        import numba
        from numba.extending import typeof_impl

        @typeof_impl.register(Kernel)
        def _typeof_kernel(val, c):             # a Kernel passed into compiled code is its dispatcher
            return numba.typeof(val.dispatcher, c.purpose)

        for k in _KERNELS:
            k.dispatcher = numba.njit(**k.options)(k.py_func)
            if command_process:
                _load_without_refresh(k.dispatcher)
        _numba = numba
        rebind()
        if command_process:
            gc.freeze()
    finally:
        if collecting:
            gc.enable()


def _import_numba() -> None:
    """``import numba``; in the command's process without PyYAML: numba imports it only to read a
    ``.numba_config.yaml`` in the working directory (14 ms here), so it is skipped when there is none."""
    import os

    if "numba" in sys.modules or not command_process or "yaml" in sys.modules \
            or os.path.exists(".numba_config.yaml"):
        import numba  # noqa: F401
        return
    sys.modules["yaml"] = None          # type: ignore[assignment]  # "import yaml" raises ImportError
    try:
        import numba  # noqa: F401
    finally:
        if sys.modules.get("yaml", 0) is None:
            del sys.modules["yaml"]


def _load_without_refresh(dispatcher) -> None:
    """Let ``dispatcher`` load its cached machine code without first refreshing numba's compiler registries.

    numba's ``Cache.load_overload`` refreshes the target context before loading: it imports and installs
    every typing and lowering registry (numba.np.*, numba.cpython.*, typed containers, jitclass: about
    250 modules' worth of declarations) that only *compiling* needs; numba's compiler refreshes them itself
    before it compiles (``CompilerBase.__init__``). Loading machine code needs the NRT runtime alone, which
    is initialised here. Per dispatcher, so other numba code in the process keeps numba's own behaviour;
    skipped (numba's own path kept) if numba's cache object does not look as expected.
    """
    cache = getattr(dispatcher, "_cache", None)
    load = getattr(type(cache), "_load_overload", None)
    guard = getattr(cache, "_guard_against_spurious_io_errors", None)
    if load is None or guard is None:
        return

    def load_overload(sig, target_context):
        _nrt_symbols(target_context)
        with guard():
            return load(cache, sig, target_context)
        return None          # the guard swallowed an I/O error: compile instead, as numba does

    cache.load_overload = load_overload


_nrt_ready = False


def _nrt_symbols(target_context) -> None:
    """Make NRT's C functions (allocation, array boxing) known to the JIT linker, which is all that cached
    machine code needs of numba's runtime: numba links its LLVM-built NRT functions (incref/decref and the
    like) into every compiled library, so the cached object code carries them. numba's own
    ``rtsys.initialize`` also builds and optimises that LLVM module (50 ms here, the only LLVM optimisation
    of a run whose kernels are all cached); it still runs, in full, before anything compiles (numba's
    registry refresh calls it). Falls back to ``rtsys.initialize`` if numba's runtime does not look as
    expected."""
    global _nrt_ready
    if _nrt_ready:
        return
    from numba.core import config
    from numba.core.runtime import rtsys

    try:
        from llvmlite import binding as ll
        from numba.core.runtime import _nrt_python

        helpers = dict(_nrt_python.c_helpers)
    except (ImportError, AttributeError, TypeError):
        helpers = None
    if helpers is None or config.NRT_STATS or getattr(rtsys, "_init", True):
        rtsys.initialize(target_context)
    else:
        for py_name, address in helpers.items():       # the names numba's rtsys.initialize gives them
            ll.add_symbol(py_name if py_name.startswith("_") else "NRT_" + py_name, address)
    _nrt_ready = True


# ---------------------------------------------------------------- cache stamps that follow dependencies
# numba stamps a cached kernel with its own source file only (its index key adds the function's bytecode):
# a kernel that inlines a function (``inline="always"``), calls a kernel or reads a constant of another
# module (numba freezes global constants into the machine code) would keep loading its old code after that
# module changed. Every kernel of gcodeplan (and of any package that makes kernels with this njit) is
# stamped with the content of every module it depends on instead (design.md, section 15).

#: top-level packages whose cached kernels get dependency stamps: gcodeplan, and any package that made a kernel
#: with :func:`njit` (a developer's prototype planner)
_STAMPED_PACKAGES = {"gcodeplan"}
_MODULE_INFO: dict = {}     # module name -> (sha256 of its file, the stamped modules it uses directly)
_STAMPS: dict = {}          # frozenset of root module names -> stamp (hex) of their dependency closure
_MISSING = object()
_from_import = None         # compiled on first use: an import statement (:func:`_import_statements`)


def _stamped(name) -> bool:
    return isinstance(name, str) and name.partition(".")[0] in _STAMPED_PACKAGES and name in sys.modules


def _defining_module(obj):
    """The name of the module ``obj`` comes from (a module, a function or kernel, a class, an instance's class);
    None when it does not say."""
    try:
        if isinstance(obj, ModuleType):
            return obj.__name__
        if isinstance(obj, (Kernel, FunctionType, type)):
            return obj.__module__
        cls_module = type(obj).__module__
        if cls_module.startswith("numba."):          # a dispatcher: the module of its Python function
            return getattr(getattr(obj, "py_func", None), "__module__", None)
        return cls_module
    except Exception:          # an object with odd attributes cannot be placed: nothing to add
        return None


def _imported_names(clause: bytes):
    """(name, bound name) of each name of the ``import`` clause of a ``from X import ...`` statement."""
    text = clause.decode("utf-8", "replace").replace("\\\n", " ")
    text = " ".join(line.split("#", 1)[0] for line in text.splitlines()).strip().strip("()")
    for part in text.split(","):
        words = part.split()
        if len(words) == 1:
            yield words[0], words[0]
        elif len(words) == 3 and words[1] == "as":
            yield words[0], words[2]


def _import_statements(data: bytes):
    """Matches of the lines of ``data`` that start an import statement: group 1 the module of ``from X import``
    (None for ``import X``), group 2 what is imported. Each "import" word is looked up with bytes.find and
    only its line matched (a multi-line regular expression tried at every byte took 7 times as long)."""
    global _from_import
    if _from_import is None:
        import re

        _from_import = re.compile(rb"[ \t]*(?:from[ \t]+(\.*[\w.]*)[ \t]+)?import[ \t]+"
                                  rb"(\([^)]*\)|(?:[^\n\\]|\\\n)*)")
    pos = data.find(b"import")
    while pos != -1:
        m = _from_import.match(data, data.rfind(b"\n", 0, pos) + 1)
        if m is not None and m.end() > pos:
            yield m
            pos = data.find(b"import", m.end())
        else:
            pos = data.find(b"import", pos + 6)


def _module_info(name: str):
    """(sha256 of the module's file, frozenset of the stamped modules its globals come from), once per process.

    A module's kernels see its globals only: a global bound to a module, a function, a kernel, a class or an
    instance names its module; a constant (a number, a tuple, an array) does not, so the file's
    ``from X import name`` statements whose name is bound, to that very object, in the module's globals name
    it (an import inside a function binds no global and adds nothing).
    """
    info = _MODULE_INFO.get(name)
    if info is not None:
        return info
    import hashlib
    import os

    mod = sys.modules.get(name)
    g = getattr(mod, "__dict__", None) or {}
    data = b""
    path = g.get("__file__")
    if path:
        try:
            with open(path, "rb") as f:
                data = f.read()
        except OSError:
            try:
                data = g["__loader__"].get_data(path)       # a zip archive's module
            except Exception:
                data = None
    # a file that cannot be read cannot be compared: a stamp that never matches (compiled in every process)
    digest = hashlib.sha256(data).digest() if data is not None else os.urandom(32)
    uses = set()
    for key, obj in list(g.items()):
        dep = _defining_module(obj)
        # a package's submodules are bound in its globals by the import system, whoever imported them: only its
        # own import statements (below) make them its dependencies
        if dep != name and _stamped(dep) and dep != f"{name}.{key}":
            uses.add(dep)
    if data:
        from importlib.util import resolve_name

        package = g.get("__package__") or name.rpartition(".")[0]
        for m in _import_statements(data):
            if m.group(1) is None:               # import a.b.c: the kernel reads a.b.c.name through global a
                for dotted, bound in _imported_names(m.group(2)):
                    if dotted == bound and _stamped(dotted) and \
                            g.get(dotted.partition(".")[0]) is sys.modules.get(dotted.partition(".")[0]):
                        uses.add(dotted)
                continue
            try:
                source = resolve_name(m.group(1).decode("ascii"), package)
            except (ImportError, ValueError, UnicodeDecodeError):
                continue
            if not _stamped(source):
                continue
            members = sys.modules[source].__dict__
            for member, bound in _imported_names(m.group(2)):
                if member == "*":
                    uses.add(source)
                    continue
                obj = g.get(bound, _MISSING)
                if obj is _MISSING:
                    continue
                if sys.modules.get(f"{source}.{member}") is obj:
                    uses.add(f"{source}.{member}")
                elif members.get(member, _MISSING) is obj:
                    uses.add(source)
    uses.discard(name)
    info = (digest, frozenset(uses))
    if not getattr(getattr(mod, "__spec__", None), "_initializing", False):
        _MODULE_INFO[name] = info           # a module still being imported may bind more globals
    return info


def _dependency_stamp(roots) -> str:
    """sha256 (hex) of the files of ``roots`` and of every stamped module they use, transitively."""
    key = frozenset(roots)
    stamp = _STAMPS.get(key)
    if stamp is not None:
        return stamp
    import hashlib

    seen = set()
    todo = [r for r in key if r in sys.modules]
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(_module_info(name)[1])
    h = hashlib.sha256()
    for name in sorted(seen):
        h.update(name.encode() + b"\0" + _module_info(name)[0])
    stamp = h.hexdigest()
    if all(name in _MODULE_INFO for name in seen):
        _STAMPS[key] = stamp
    return stamp


def _kernel_stamp(py_func, py_file: str, own_file_stamp) -> str:
    """The cache stamp of ``py_func`` (numba's index key adds its bytecode): the closure of its module and of the
    modules of what its closure cells hold; numba's stamp of ``py_file`` (``own_file_stamp()``) joins in when
    that is not the module's file."""
    import os

    g = getattr(py_func, "__globals__", None) or {}
    root = g.get("__name__")
    roots = {root} if root in sys.modules else set()
    for cell in getattr(py_func, "__closure__", None) or ():
        try:
            dep = _defining_module(cell.cell_contents)
        except ValueError:        # an empty cell
            continue
        if _stamped(dep):
            roots.add(dep)
    stamp = _dependency_stamp(roots)
    own = getattr(sys.modules.get(root), "__file__", None)
    if not own or os.path.normcase(os.path.abspath(own)) != os.path.normcase(os.path.abspath(py_file)):
        import hashlib

        stamp = hashlib.sha256((stamp + repr(own_file_stamp())).encode()).hexdigest()
    return stamp


class _LazyStamp:
    """A cache stamp computed when numba first compares or saves it (numba asks for it when it makes the
    dispatcher, before the module has finished importing, and for every kernel whether it runs or not). It
    equals its value and pickles as that plain string, so a saved index holds no gcodeplan object."""

    __slots__ = ("_compute", "_value")

    def __init__(self, compute):
        self._compute = compute
        self._value = None

    def value(self) -> str:
        if self._value is None:
            self._value = self._compute()
        return self._value

    def __eq__(self, other):
        if isinstance(other, _LazyStamp):
            other = other.value()
        return self.value() == other

    def __ne__(self, other):
        return not self.__eq__(other)

    def __hash__(self):
        return hash(self.value())

    def __reduce__(self):
        return (str, (self.value(),))

    def __repr__(self) -> str:
        return f"<gcodeplan cache stamp {self.value()}>"


_stamp_locator = None


def _install_dependency_stamps() -> None:
    """Put a cache locator in front of numba's own ones for the kernels of :data:`_STAMPED_PACKAGES`: it keeps
    the directory numba would choose (``NUMBA_CACHE_DIR``, the ``__pycache__`` beside the file, the user-wide
    directory when that is not writable...) and stamps with :func:`_kernel_stamp`. Other functions, and
    ``NUMBA_CACHE_LOCATOR_CLASSES`` when set, keep numba's behaviour. Skipped (numba's own stamps) if numba's
    caching module does not look as expected."""
    global _stamp_locator
    if _stamp_locator is not None:
        return
    try:
        from numba.core import caching

        impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
        base = caching._CacheLocator
        numba_locators = [c for c in impl._locator_classes if not getattr(c, "_gcodeplan_stamps", False)]
    except (ImportError, AttributeError, TypeError):
        return

    class DependencyStampLocator(base):
        """numba's locator for the function, with :func:`_kernel_stamp` as its source stamp."""

        _gcodeplan_stamps = True

        def __init__(self, inner, py_func, py_file):
            self._inner = inner
            self._py_func = py_func
            self._py_file = py_file

        def ensure_cache_path(self):
            return self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        def get_source_stamp(self):
            return _LazyStamp(lambda: _kernel_stamp(self._py_func, self._py_file, self._inner.get_source_stamp))

        @classmethod
        def from_function(cls, py_func, py_file):
            module = getattr(py_func, "__module__", None)
            if not isinstance(module, str) or module.partition(".")[0] not in _STAMPED_PACKAGES:
                return None
            for locator_class in numba_locators:
                inner = locator_class.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, py_func, py_file)
            return None

    impl._locator_classes = [DependencyStampLocator, *numba_locators]
    _stamp_locator = DependencyStampLocator


def rebind() -> None:
    """Replace every :class:`Kernel` in gcodeplan's module globals by its dispatcher (numba resolves a
    kernel's callees through these globals when it compiles, and calls skip the wrapper)."""
    if _numba is None:
        return
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name == "gcodeplan" or name.startswith("gcodeplan.")):
            continue
        d = getattr(mod, "__dict__", None)
        if not d:
            continue
        for attr, val in list(d.items()):
            if type(val) is Kernel and val.dispatcher is not None:
                d[attr] = val.dispatcher


def active() -> bool:
    """True once numba is imported and the kernels are compiled dispatchers."""
    return _numba is not None


@contextmanager
def interpreted(enabled: bool = True):
    """Run kernels as Python inside the block while numba is not yet imported (tiny inputs; module docstring).

    Once numba is active this does nothing: compiled kernels are then the cheaper choice.
    """
    global _interpret_depth
    if not enabled:
        yield
        return
    _interpret_depth += 1
    try:
        yield
    finally:
        _interpret_depth -= 1


__all__ = ["njit", "Kernel", "activate", "active", "interpreted", "is_kernel", "compiled", "numba_module",
           "SMALL_INPUT_BYTES"]
