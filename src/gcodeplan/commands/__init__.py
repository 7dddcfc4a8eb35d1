"""The command line's commands, one module each (``add_arguments(parser)`` and ``run(args) -> int``).

They sit on top of the library: each builds its machine and options here and calls
:mod:`gcodeplan.pipeline` or the public API; no stage package imports this package.
"""
