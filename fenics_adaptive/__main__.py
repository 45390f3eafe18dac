"""``python -m fenics_adaptive``: the command line (``fenics_adaptive.cli``)."""

import sys

from fenics_adaptive.cli import main

if __name__ == "__main__":  # not on import (the documentation's API pages import every module)
    sys.exit(main())
