import sys

from fenics_adaptive.cli import main

sys.exit(main())
