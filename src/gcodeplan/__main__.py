"""``python -m gcodeplan …`` runs the ``gcodeplan`` command (the same :func:`gcodeplan.cli.main`)."""
import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
