"""``load_machine``: which reader a machine spec names (a preset, a TOML file, a grbl ``$$`` report or a
Marlin ``M503`` report).

It sits above the readers (:mod:`.toml`, :mod:`.grbl_settings`, :mod:`.marlin_report`) so that they
need not know each other: the two report readers start from a preset read by :mod:`.toml`.
"""
from __future__ import annotations

import difflib
import os

from ..errors import ConfigError
from ..machine import Machine
from .grbl_settings import is_grbl_settings, load_grbl_settings
from .marlin_report import is_marlin_report, load_marlin_report
from .toml import load_machine_toml, load_preset, preset_names


def load_machine(path_or_preset: str) -> Machine:
    """A machine from a TOML file, or from a preset name (``klipper``, ``marlin``, ``grbl``).

    An existing regular file wins over a preset of the same name; a directory never does.
    """
    spec = str(path_or_preset)
    if spec.endswith(".cfg"):
        if not os.path.exists(spec):
            raise ConfigError("no such file", spec)
        raise ConfigError("this looks like a Klipper printer.cfg: use --klipper-config for it", spec)
    if os.path.isfile(spec):
        if is_grbl_settings(spec):            # grbl's $$ report
            return load_grbl_settings(spec)
        if is_marlin_report(spec):            # Marlin's M503 report
            return load_marlin_report(spec)
        return load_machine_toml(spec)
    presets = preset_names()
    if spec in presets:
        return load_preset(spec)
    if os.sep in spec or "/" in spec or spec.endswith(".toml") or os.path.exists(spec):
        return load_machine_toml(spec)
    close = difflib.get_close_matches(spec, presets, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ConfigError(f"machine {spec!r} is neither a file nor a preset; presets: {', '.join(presets)}{hint}")
