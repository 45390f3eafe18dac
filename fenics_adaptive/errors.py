"""The one exception type for bad user input (configs, layups, mesh parameters), and the way an
error found on some ranks reaches all of them.

Under MPI an exception raised on one rank only leaves the others waiting in their next
collective for ever. Code that can fail on part of the ranks (rank 0 makes a folder, Gmsh
meshes on rank 0, a face lies on one rank's cells) runs inside ``shared_errors(comm)``: the
block's exception, if any, is exchanged once, collectively, and every rank raises the same
error (the lowest failing rank's), so all ranks exit alike and the message is printed once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager


class InputError(ValueError):
    """Bad user input. The message is one line that starts with the offending key, e.g.
    ``materials.carbon.E1: must be > 0 (got -1.0)``."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}" if key else problem)


class RemoteError(RuntimeError):
    """The error another rank raised inside ``shared_errors``, raised on this rank: the run
    cannot go on without the failing rank."""

    def __init__(self, rank: int, kind: str, message: str):
        self.rank, self.kind = rank, kind
        super().__init__(f"{kind} on rank {rank}: {message}")


@contextmanager
def shared_errors(comm) -> Iterator[None]:
    """Run a block whose exception may occur on some ranks only; collective (one allgather on
    every rank, whether the block failed or not).

    Every rank then raises: the failing rank its own exception, every other rank the lowest
    failing rank's ``InputError`` as an ``InputError`` with the same key and text (so that the
    command line exits 2 on all ranks), or any other exception as a ``RemoteError``.

    Parameters:
        comm: the MPI communicator of the ranks that must agree (mpi4py ``Comm``).
    """
    failure: BaseException | None = None
    try:
        yield
    except Exception as error:  # KeyboardInterrupt and SystemExit are not shared: they end the rank
        failure = error
    summary = None
    if failure is not None:
        key = failure.key if isinstance(failure, InputError) else None
        problem = failure.problem if isinstance(failure, InputError) else str(failure)
        summary = (type(failure).__name__, key, problem)
    reports = comm.allgather(summary) if comm.size > 1 else [summary]
    if failure is not None:
        raise failure
    for rank, report in enumerate(reports):
        if report is None:
            continue
        kind, key, problem = report
        if key is not None:
            raise InputError(key, problem)
        raise RemoteError(rank, kind, problem)


def script_main(main: Callable[[], object], name: str) -> None:
    """Run a script's ``main`` as the command line runs its commands: a bad input ends it
    with one line on stderr (the script's name, then the key and the problem) and exit
    status 2, not a traceback. For the demos' ``if __name__ == "__main__"`` blocks.

    Parameters:
        main: the script's entry point, called without arguments.
        name: the script's name as the user typed it (e.g. ``demos/tcb.py``).
    """
    import sys

    try:
        main()
    except InputError as error:
        print(f"{name}: {error}", file=sys.stderr)
        raise SystemExit(2) from None
