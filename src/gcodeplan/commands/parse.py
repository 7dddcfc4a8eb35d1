"""``gcodeplan parse FILE``: what a G-code file contains (moves, layers, distances, filament, naive time)."""
from __future__ import annotations

import argparse
import gc
import json
import os
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .common import add_machine_arguments

    p.add_argument("file", help="G-code file")
    add_machine_arguments(p)   # also adds --strict
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def _machine(args):
    try:
        from ..config import machine_from_args
    except ImportError:   # config module not there yet: the built-in defaults
        from ..machine import Machine

        m = Machine()
        if getattr(args, "flavor", None):
            m.flavor = args.flavor
        return m
    return machine_from_args(args)


def _own_process() -> bool:
    """True when this process is the ``gcodeplan`` command itself (not a test run, not a program
    calling :func:`gcodeplan.cli.main`)."""
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    return os.path.basename(sys.argv[0]) == "gcodeplan" or getattr(spec, "name", None) == "gcodeplan.cli"


def run(args: argparse.Namespace) -> int:
    own = _own_process()
    if own and "numpy" not in sys.modules:
        # the parser does no linear algebra: spare the start-up of OpenBLAS's thread pool
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from .. import _jit
    from ..pipeline import open_reader

    machine = _machine(args)
    reader, small = open_reader(args.file, machine, strict=bool(getattr(args, "strict", False)))
    if own:
        # Process-wide start-up shortcut, safe only when this process is the `gcodeplan parse` command:
        # what is alive now (the modules) goes to the permanent GC generation, which spares later
        # collections and the interpreter's final one from walking it (those objects live until exit).
        gc.freeze()
    with _jit.interpreted(small):       # a tiny file: no numba start-up (gcodeplan/_jit.py)
        for _ in reader.batches():
            pass
    s = reader.summary
    if args.json:
        json.dump(s.to_json(), sys.stdout)
        sys.stdout.write("\n")
    else:
        print(s.text())
    return 0
