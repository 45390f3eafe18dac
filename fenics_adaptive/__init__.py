"""fenics-adaptive: the adaptive thick-shell element for explicit dynamics of laminates, on FEniCSx.

Units throughout: N, mm, s, tonne (stress MPa, density tonne/mm^3, energy mJ = N mm).
"""

# mpi4py first: the DOLFINx wheel finds libmpi through it, whatever order modules import in.
from mpi4py import MPI  # noqa: F401

__version__ = "0.1.0"
