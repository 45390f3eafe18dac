"""Sums over the ranks in one MPI call.

mpi4py's object collectives (``comm.allreduce(x)``) pickle their argument and, on MPICH, take a
reduction to one rank and a broadcast back: two waits per sum (``benchmarks/sync_points.py``
counts them). ``summed`` is one ``MPI_Allreduce`` of a float64 buffer.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from mpi4py import MPI

__all__ = ["summed"]


def summed(comm: MPI.Comm, local: np.ndarray | Sequence[float]) -> np.ndarray:
    """Collective: the elementwise sum over the ranks of ``local`` (as float64; a new array).
    On one rank a copy, no MPI call."""
    values = np.array(local, dtype=np.float64)
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, values, op=MPI.SUM)
    return values
