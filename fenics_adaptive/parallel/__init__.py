"""Parallel machinery: the halo exchange of the explicit step (``halo.Halo``), one thread per
rank for the libraries that start their own (``threads.one_thread_per_rank``), what a cell
costs and how unequally the ranks share it (``balance``), and a model of the step on many
ranks (``scaling``).

The MPI collectives of the model and its solver live with what they compute; what is here is
shared by several of them.
"""

from fenics_adaptive.parallel.halo import Halo
from fenics_adaptive.parallel.threads import one_thread_per_rank

__all__ = ["Halo", "one_thread_per_rank"]
