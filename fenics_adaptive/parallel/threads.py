"""One BLAS/OpenMP thread per MPI rank.

The step's kernels are compiled single-threaded (numba, no ``parallel=True``): the parallelism of a
run is its MPI ranks. numpy's BLAS, left alone, starts a pool of threads per process, one per
core; with several ranks on a machine those pools hold more threads than cores, and a BLAS call
on one rank (the dot products of a history row) spins against the other ranks' threads and
against MPI's own busy wait. Measured on this project's two-vCPU machines, 4 000-cell beam, two
ranks: a history row 15.2 ms with the default pools, 0.92 ms with one thread per rank (one rank:
1.45 ms); a 200-step run 1.50 against 1.00 ms per step. So a run on several ranks limits each
rank's pools to one thread, as PETSc and DOLFINx advise for MPI runs. One rank keeps the
machine's settings: the time loop hands the BLAS none of its long vectors (their dot products
are ``reductions.dot``, in the rank's thread: a pool woken for a vector of the plate impact's
15 606 DOFs spun against another process on the second core, 7.7 ms a dot).
"""

from __future__ import annotations

from mpi4py import MPI

__all__ = ["one_thread_per_rank"]

_limited = False


def one_thread_per_rank(comm: MPI.Comm) -> bool:
    """Limit this process's BLAS and OpenMP thread pools to one thread if ``comm`` has several
    ranks (for the rest of the process: the pools are the process's). Returns whether it did.
    Local: no communication."""
    global _limited
    if comm.size == 1:
        return False
    if not _limited:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
        _limited = True
    return True
