"""Kinematics as plug-ins: one registry for the built-in machines and the user's own.

A kinematics plug-in says three things (Klipper's kinematics classes say the same, with the step solver
itersolve.c shared between them):

* its motors: name, steps per unit of motor position (mm, or rad for a rotary joint) and how the motor
  position follows from the toolhead (x, y, z): either fixed weights over (x, y, z[, e]) (a linear motor,
  stepped by the exact polynomial kernel) or an **inverse-kinematics function** ``ik(x, y, z, params) ->
  motor position``, compiled with numba: the position callback of the one step search
  (:func:`gcodeplan.stepper.kernel.itersolve_steps`, Klipper's itersolve.c with its calc_position callback);
* an optional **limits hook** ``check_move(move, params) -> (speed cap mm/s, accel cap mm/s², error code)``,
  compiled with numba: Klipper's ``check_move``, applied by the planner to every move as it streams
  (``move`` is a float64 vector indexed by the ``MV_*`` constants below; ``inf`` = no cap; a non-zero error
  code refuses the move, :meth:`Plugin.move_error` gives its text);
* its parameters: a float64 array handed to both functions (arm lengths, anchors, …), made from the
  machine (``machine.kinematics_params``, which a machine TOML's ``[kinematics_params]`` table or the
  printer.cfg reader fills).

    import numba, numpy as np, gcodeplan as gp

    @numba.njit
    def radius(x, y, z, p):
        return np.sqrt(x * x + y * y)

    gp.kinematics.register("my_polar", gp.kinematics.Plugin(
        {"arm": radius, "z": (0, 0, 1)}, steps_per_unit={"arm": 80.0, "z": 400.0}))

A registered name is a kinematics everywhere a built-in's is (``Machine.kinematics``, a machine file's
``kinematics = "…"``, ``--plugin FILE.py`` files that register one, :func:`gcodeplan.kinematics.rails_for`).
"""
from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping

import numpy as np

from .. import _jit
from .._jit import njit
from ..errors import ConfigError
from .rail import AXIS_FIELDS, KINEMATICS_MODULES, Rail

# the move vector a check_move hook sees (float64, mm, mm/s, mm/s²)
MV_X0, MV_Y0, MV_Z0, MV_X1, MV_Y1, MV_Z1 = 0, 1, 2, 3, 4, 5   # start and end of the move (mm)
MV_MOVE_D = 6          # mm, XYZ length
MV_MAX_CRUISE_V2 = 7   # mm²/s², the cruise cap when Klipper calls check_move (requested speed, max_velocity,
                       # per-axis limits; before the extruder's rule)
MV_ACCEL = 8           # mm/s², the acceleration at that point
MOVE_VECTOR_LEN = 9

#: error code 1 of every hook: the move leaves the reachable volume (Klipper's "Move out of range")
ERR_OUT_OF_RANGE = 1


@njit(cache=True)
def no_check_move(move, params):
    """The limits hook of a kinematics without limits of its own (winch): no cap, no error."""
    return math.inf, math.inf, 0


class Plugin:
    """A kinematics plug-in (module docstring).

    ``motors``: motor name → an inverse-kinematics function ``ik(x, y, z, params)`` (numba-compiled; a plain
    Python function is compiled with ``numba.njit``) or weights over (x, y, z[, e]) for a linear motor; in
    output order. ``steps_per_unit``: motor name → steps per unit of motor position (a number or a function
    of the machine); a motor without one takes the machine's ``[axis]`` steps/mm of its first axis with a
    weight (linear motors only). ``params``: the float array both functions receive, or a function of the
    machine returning it. ``check_move``: the limits hook (None: none). ``periods``: motor name → period of a
    cyclic motor position (2π for a turntable: followed continuously). ``klipper_names``: motor name →
    Klipper's section name. ``extruder``: the name of the automatic extruder motor (E, the machine's steps/mm),
    None for none. ``motor_params``: motor name → that motor's own ik parameters (array or function of the
    machine; Klipper gives each stepper its own, e.g. a rotary delta arm's angle), instead of ``params``.
    ``errors``: error code → message of the limits hook's refusals. ``from_klipper``: a
    function ``(cfg, machine)`` that reads this kinematics' printer.cfg sections (config/klipper.py calls it).
    """

    def __init__(self, motors: Mapping[str, object], steps_per_unit: Mapping[str, object] | None = None, *,
                 params: object = (), check_move=None, periods: Mapping[str, float] | None = None,
                 klipper_names: Mapping[str, str] | None = None, extruder: str | None = "extruder",
                 errors: Mapping[int, str] | None = None, from_klipper: Callable | None = None,
                 motor_params: Mapping[str, object] | None = None):
        if not isinstance(motors, Mapping) or not motors:
            raise ConfigError("kinematics plug-in: motors must be a non-empty {name: ik function or weights} dict")
        self.motors: dict[str, object] = {}
        for name, pos in motors.items():
            if not isinstance(name, str) or not name:
                raise ConfigError(f"kinematics plug-in: motor names must be non-empty strings, got {name!r}")
            if callable(pos):
                self.motors[name] = _compiled(pos)
            else:
                try:
                    w = tuple(float(x) for x in pos)
                except (TypeError, ValueError):
                    raise ConfigError(f"kinematics plug-in: motor {name}: expected an ik function or 3-4 weights, "
                                      f"got {pos!r}") from None
                if len(w) not in (3, 4) or not all(math.isfinite(x) for x in w) or not any(w):
                    raise ConfigError(f"kinematics plug-in: motor {name}: weights must be 3 or 4 finite numbers, "
                                      f"not all zero, got {pos!r}")
                self.motors[name] = w + (0.0,) * (4 - len(w))
        self.steps_per_unit = dict(steps_per_unit or {})
        unknown = set(self.steps_per_unit) - set(self.motors)
        if unknown:
            raise ConfigError(f"kinematics plug-in: steps_per_unit names unknown motor(s) {sorted(unknown)}")
        self.params = params
        self.check_move = None if check_move is None else _compiled(check_move)
        self.periods = dict(periods or {})
        self.klipper_names = dict(klipper_names or {})
        self.extruder = extruder
        self.errors = {ERR_OUT_OF_RANGE: "Move out of range", **dict(errors or {})}
        self.from_klipper = from_klipper
        self.motor_params = dict(motor_params or {})
        self.name = "plugin"

    # ---------------------------------------------------------------- what the stages ask
    def param_array(self, machine) -> np.ndarray:
        """The float64 parameter array of ``machine`` (ConfigError when it cannot be made)."""
        return self._array(self.params, machine)

    def _array(self, spec, machine) -> np.ndarray:
        p = spec(machine) if callable(spec) else spec
        try:
            arr = np.ascontiguousarray(np.asarray(p, dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise ConfigError(f"kinematics {self.name!r}: params must be numbers, got {p!r}") from None
        if arr.size == 0:
            arr = np.zeros(1)      # numba needs a typed array even when the functions read none
        return arr

    def rails(self, machine, klipper_names: bool = False) -> list[Rail]:
        """The motors as :class:`Rail` rows (the extruder last), Klipper's names with ``klipper_names``."""
        params = None
        out = []
        for name, pos in self.motors.items():
            shown = self.klipper_names.get(name, name) if klipper_names else name
            spu = self.steps_per_unit.get(name)
            if callable(spu):
                spu = spu(machine)
            if isinstance(pos, tuple):
                if spu is None:
                    if machine is None:
                        raise ConfigError(f"kinematics {self.name!r}: motor {name}: no steps_per_unit")
                    axis = next(ax for ax, x in zip(AXIS_FIELDS, pos) if x != 0.0)
                    spu = float(machine.axes[axis].steps_per_mm)
                out.append(Rail(shown, float(spu), pos))
                continue
            if spu is None:
                raise ConfigError(f"kinematics {self.name!r}: motor {name}: steps_per_unit is required for a "
                                  f"motor given by an ik function")
            own = self.motor_params.get(name)
            if own is not None:
                mp = tuple(float(v) for v in self._array(own, machine))
            else:
                if params is None:
                    params = tuple(float(v) for v in self.param_array(machine))
                mp = params
            out.append(Rail(shown, float(spu), None, ik=pos, ik_params=mp,
                            period=float(self.periods.get(name, 0.0))))
        if self.extruder is not None and not any(isinstance(p, tuple) and p[3] for p in self.motors.values()):
            spm = float(machine.axes["e"].steps_per_mm) if machine is not None else 0.0
            out.append(Rail(self.extruder if klipper_names or self.extruder != "extruder" else "e", spm,
                            (0.0, 0.0, 0.0, 1.0)))
        return out

    def move_error(self, code: int) -> str:
        """The text of a limits-hook refusal with error ``code``."""
        return self.errors.get(int(code), f"kinematics {self.name!r} refuses this move (code {int(code)})")

    def __repr__(self) -> str:
        return f"<kinematics plug-in {self.name!r}: {', '.join(self.motors)}>"


def _compiled(fn):
    """``fn`` as given: a Python function, a gcodeplan kernel or a numba function (it is made a cfunc, compiled,
    when a stage first needs it: :func:`ik_cfunc`, :func:`hook_cfunc`)."""
    if not callable(fn):
        raise ConfigError(f"kinematics plug-in: expected a function, got {fn!r}")
    return fn


_CFUNCS: dict = {}


def _cfunc(key, make):
    fn = _CFUNCS.get(key)
    if fn is None:
        fn = _CFUNCS[key] = make()
    return fn


def _py(fn):
    """The Python source function of a numba dispatcher or gcodeplan kernel (the function itself otherwise)."""
    return getattr(fn, "py_func", fn)


def ik_cfunc(fn):
    """An inverse-kinematics function ``(x, y, z, params) -> float`` as a numba cfunc of that one signature
    (float64 × 3, float64[::1] → float64): the generic step engine takes it as a function pointer, so the
    engine is compiled and cached once for every plug-in. Cached on disk when numba can (a function from a
    file), per process otherwise. (Handing the engine the numba dispatcher instead would specialise it per ik
    and inline the call — about a quarter fewer ns per step on the cube — but numba keys such a specialisation
    by the dispatcher's per-process identity, so it would compile the whole engine again in every process.)"""
    def make():
        numba = _jit.numba_module()
        t = numba.types
        sig = t.float64(t.float64, t.float64, t.float64, t.Array(t.float64, 1, "C"))
        # error_model "numpy": a division by zero gives inf / NaN (reported as unreachable), as in C; an
        # exception cannot leave a cfunc
        try:
            return numba.cfunc(sig, cache=True, error_model="numpy")(_py(fn))
        except Exception:          # no cache locator (a function typed into a REPL or exec'd): compile only
            return numba.cfunc(sig, error_model="numpy")(_py(fn))

    return _cfunc(("ik", fn), make)


def ik_bound_cfunc(fn, params):
    """An inverse-kinematics function with its parameters bound: a numba cfunc ``(x, y, z) -> float`` calling
    ``fn(x, y, z, params)`` with ``params`` (float64 array) frozen into the compiled code as a constant — what the
    step engine's guarded search calls (:func:`gcodeplan.stepper.kernel.gen_steps_ik`). An array handed to compiled
    code at every call costs two reference counts per call, more than the call itself; a constant costs nothing
    and lets the compiler fold it. Compiled once per (function, parameters) and process (about 0.1 s; numba cannot
    cache a function of a constant it did not read from a file)."""
    frozen = np.array(params, dtype=np.float64).reshape(-1)
    if frozen.size == 0:
        frozen = np.zeros(1)
    frozen.setflags(write=False)

    def make():
        numba = _jit.numba_module()
        t = numba.types
        # error_model "numpy": a division by zero gives inf / NaN (reported as unreachable), as in C
        inner = numba.njit(error_model="numpy")(_py(fn))
        bound = frozen

        def ik_bound(x, y, z):
            return inner(x, y, z, bound)

        return numba.cfunc(t.float64(t.float64, t.float64, t.float64), error_model="numpy")(ik_bound)

    return _cfunc(("ik_bound", fn, frozen.tobytes()), make)


def hook_cfunc(fn):
    """A limits hook ``check_move(move, params) -> (speed cap, accel cap, error)`` as a cfunc
    ``(move, params, caps) -> error`` writing the caps into ``caps[0:2]`` (what the planner's kernel calls)."""
    def make():
        numba = _jit.numba_module()
        t = numba.types
        arr = t.Array(t.float64, 1, "C")
        # error_model "numpy": an exception cannot leave the cfunc (a division by zero gives inf / NaN)
        inner = numba.njit(error_model="numpy")(_py(fn))

        def check_move_caps(move, params, caps):
            v_cap, a_cap, err = inner(move, params)
            caps[0] = v_cap
            caps[1] = a_cap
            return err

        return numba.cfunc(t.int64(arr, arr, arr), error_model="numpy")(check_move_caps)

    return _cfunc(("hook", fn), make)


# ---------------------------------------------------------------- registry
_REGISTRY: dict[str, object] = {}


def register(name: str, plugin, *, replace: bool = False):
    """Add kinematics ``name``: a :class:`Plugin` (or any object with ``rails(machine, klipper_names)`` and,
    optionally, ``check_move``/``param_array(machine)``/``move_error(code)``/``from_klipper(cfg, machine)``).
    Usable as ``Machine.kinematics`` from then on. Built-in names cannot be replaced; a user's name can with
    ``replace=True``. Returns the plug-in."""
    if not isinstance(name, str) or not name.strip() or any(c.isspace() for c in name):
        raise ConfigError(f"kinematics.register: the name must be a non-empty word, got {name!r}")
    if not callable(getattr(plugin, "rails", None)):
        raise ConfigError("kinematics.register: a plug-in needs rails(machine, klipper_names) (use "
                          "gcodeplan.kinematics.Plugin)")
    builtin = name in KINEMATICS_MODULES
    if builtin and getattr(plugin, "_builtin_of", None) != name:
        raise ConfigError(f"kinematics.register: {name!r} is a built-in kinematics")
    if name in _REGISTRY and not replace and not builtin:
        raise ConfigError(f"kinematics.register: kinematics {name!r} exists (replace=True)")
    if isinstance(plugin, Plugin):
        plugin.name = name
    _REGISTRY[name] = plugin
    return plugin


def unregister(name: str) -> None:
    """Remove a user's kinematics."""
    if name in KINEMATICS_MODULES or name not in _REGISTRY:
        raise ConfigError(f"kinematics.unregister: {name!r} is not a registered user kinematics")
    del _REGISTRY[name]


def registered(name: str):
    """The plug-in registered as ``name``, None when there is none (built-ins register on first import)."""
    if name not in _REGISTRY and name in KINEMATICS_MODULES:
        importlib.import_module(f"{__package__}.{KINEMATICS_MODULES[name]}")
    return _REGISTRY.get(name)


def names() -> list[str]:
    """Every kinematics name: the built-ins, then the user's."""
    return list(KINEMATICS_MODULES) + [n for n in _REGISTRY if n not in KINEMATICS_MODULES]


def limits_hook(machine):
    """(check_move function, params, plug-in) of the machine's kinematics, None when it has no hook."""
    if machine is None:
        return None
    plugin = registered(machine.kinematics)
    fn = getattr(plugin, "check_move", None) if plugin is not None else None
    if fn is None:
        return None
    return hook_cfunc(fn), plugin.param_array(machine), plugin
