"""``load_machine``: which reader a machine spec names (a preset, a TOML file, a Klipper ``printer.cfg``, a
LinuxCNC ``.ini``, a grbl ``$$`` report, a Marlin ``M503`` report or ``Configuration.h``).

It sits above the readers (:mod:`.toml`, :mod:`.klipper`, :mod:`.linuxcnc`, :mod:`.grbl_settings`,
:mod:`.marlin_report`, :mod:`.marlin_config`) so that they need not know each other: the report readers start
from a preset read by :mod:`.toml`.
"""
from __future__ import annotations

import difflib
import os

from ..errors import ConfigError
from ..machine import Machine
from .grbl_settings import is_grbl_settings, load_grbl_settings
from .klipper import load_klipper_config
from .linuxcnc import is_linuxcnc_ini, load_linuxcnc_ini
from .marlin_config import is_marlin_config, load_marlin_config
from .marlin_report import is_marlin_report, load_marlin_report
from .toml import load_machine_toml, load_preset, preset_names


def load_machine(path_or_preset: str) -> Machine:
    """A machine from a TOML file, or from a preset name (``klipper``, ``marlin``, ``grbl``), or from what the
    machine's owner has: a Klipper ``printer.cfg`` (by its ``.cfg`` name), a LinuxCNC ``.ini``, grbl's ``$$``
    report, Marlin's ``M503`` report or its ``Configuration.h`` (each recognised by its content).

    An existing regular file wins over a preset of the same name; a directory never does.
    """
    spec = str(path_or_preset)
    if spec.endswith(".cfg"):
        if not os.path.exists(spec):
            raise ConfigError("no such file", spec)
        return load_klipper_config(spec)      # Klipper's printer.cfg, read as --klipper-config reads it
    if os.path.isfile(spec):
        if is_linuxcnc_ini(spec):             # a LinuxCNC machine .ini, read as --linuxcnc-ini reads it
            return load_linuxcnc_ini(spec)
        if is_grbl_settings(spec):            # grbl's $$ report
            return load_grbl_settings(spec)
        if is_marlin_report(spec):            # Marlin's M503 report
            return load_marlin_report(spec)
        if is_marlin_config(spec):            # Marlin's Configuration.h (+ Configuration_adv.h beside it)
            return load_marlin_config(spec)
        return load_machine_toml(spec)
    presets = preset_names()
    if spec in presets:
        return load_preset(spec)
    if os.sep in spec or "/" in spec or spec.endswith(".toml") or os.path.exists(spec):
        return load_machine_toml(spec)
    close = difflib.get_close_matches(spec, presets, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ConfigError(f"machine {spec!r} is neither a file nor a preset; presets: {', '.join(presets)}{hint}")
