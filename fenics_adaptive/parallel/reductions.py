"""Sums over the ranks in one MPI call, and the rank's own part of them in its own thread.

mpi4py's object collectives (``comm.allreduce(x)``) pickle their argument and, on MPICH, take a
reduction to one rank and a broadcast back: two waits per sum (``benchmarks/sync_points.py``
counts them). ``summed`` is one ``MPI_Allreduce`` of a float64 buffer.

``dot`` is the time loop's dot product of two vectors. numpy's goes to the BLAS, which on one
rank keeps a pool of one thread per core (``threads``: several ranks limit it to one) and wakes
it for vectors of some thousands of entries: on the impact plate's 15 606 base DOFs a history
row's dot took 7.7 ms with the other core busy against 3 us in one thread.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from mpi4py import MPI
from numba import njit

__all__ = ["dot", "summed"]


@njit(cache=True)
def dot(a: np.ndarray, b: np.ndarray) -> float:
    """sum_i a_i b_i of two float64 vectors of one length, in this thread."""
    total = 0.0
    for i in range(a.shape[0]):
        total += a[i] * b[i]
    return total


def summed(comm: MPI.Comm, local: np.ndarray | Sequence[float]) -> np.ndarray:
    """Collective: the elementwise sum over the ranks of ``local`` (as float64; a new array).
    On one rank a copy, no MPI call."""
    values = np.array(local, dtype=np.float64)
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, values, op=MPI.SUM)
    return values
