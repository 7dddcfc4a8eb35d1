"""Machine configuration: gcodeplan's TOML format, Klipper's printer.cfg, presets, validation.

Everything here produces a :class:`gcodeplan.machine.Machine` (the contract; units mm, s, mm/s,
mm/s², mm/s³; ``inf`` = no limit). Every bad value raises :class:`ConfigError` naming the file and
the key (and the line, for printer.cfg), so the CLI prints one line instead of a traceback.

The TOML keys are listed, with units and defaults, in ``docs/machine.md``; the table ``FIELDS``
in :mod:`.fields` is the single source of truth for them (loader, validation and writer all use it).
"""
from __future__ import annotations


import math
from dataclasses import replace
from typing import Any

from ..errors import ConfigError
from .fields import (klipper_extrude_ratio, parse_gear_ratio, rule_choice, steps_per_mm_from_rotation,  # noqa: F401
                     validate)
from .toml import load_machine_toml, machine_to_toml, preset_names, preset_path  # noqa: F401
from .klipper import KlipperCfg, load_klipper_config  # noqa: F401
from .load import load_machine
from ..machine import FLAVORS, Machine


__all__ = ["load_machine", "load_machine_toml", "load_klipper_config", "machine_from_args", "machine_to_toml",
           "preset_names", "preset_path", "validate", "steps_per_mm_from_rotation", "parse_gear_ratio",
           "klipper_extrude_ratio", "without_bounds", "KlipperCfg"]

# ============================================================================ CLI

def machine_from_args(args: Any) -> Machine:
    """The machine a command runs with: ``--machine`` (TOML or preset) or ``--klipper-config``,
    default the ``klipper`` preset; ``--flavor`` overrides the machine's flavor."""
    machine_spec = getattr(args, "machine", None)
    klipper_cfg = getattr(args, "klipper_config", None)
    linuxcnc_ini = getattr(args, "linuxcnc_ini", None)
    if sum(bool(x) for x in (machine_spec, klipper_cfg, linuxcnc_ini)) > 1:
        raise ConfigError("give one of --machine, --klipper-config, --linuxcnc-ini, not both")
    if linuxcnc_ini:
        from .linuxcnc import load_linuxcnc_ini

        machine = load_linuxcnc_ini(linuxcnc_ini)
    elif klipper_cfg:
        machine = load_klipper_config(klipper_cfg)
    else:
        machine = load_machine(machine_spec or "klipper")
    flavor = getattr(args, "flavor", None)
    if not (machine_spec or klipper_cfg or linuxcnc_ini or flavor):
        machine = replace(machine, auto_flavor=True)     # the default preset: a CNC program may pick its flavor
    if flavor:
        problem = rule_choice(FLAVORS)(flavor)
        if problem is not None:
            raise ConfigError(f"--flavor: {problem}")
        machine = replace(machine, flavor=flavor)
    firmware = getattr(args, "firmware", None)
    if firmware:
        from ..machine import FIRMWARES, with_firmware

        problem = rule_choice(FIRMWARES)(firmware)
        if problem is not None:
            raise ConfigError(f"--firmware: {problem}")
        machine = with_firmware(machine, firmware)
    if getattr(args, "no_bounds", False):
        machine = without_bounds(machine)
    return machine


def without_bounds(machine: Machine) -> Machine:
    """A copy of ``machine`` with no travel limits (position_min/max ∓inf) on any axis: ``--no-bounds``."""
    axes = {a: replace(ax, position_min=-math.inf, position_max=math.inf) for a, ax in machine.axes.items()}
    return replace(machine, axes=axes)
