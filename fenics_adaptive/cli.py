"""Command line: ``fenics-adaptive run CONFIG.toml --out DIR [--restart CHECKPOINT]
[--overwrite]`` and ``fenics-adaptive check``.

Exit status: 0 done, 2 bad input (one line on stderr naming the key), 1 the run failed, 130 the
run was interrupted (SIGINT or SIGTERM) after writing a checkpoint to continue from.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
import traceback

from mpi4py import MPI

from fenics_adaptive.errors import InputError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="fenics-adaptive",
        description="Explicit dynamics of laminated beams and plates with the adaptive "
        "thick-shell element (units: N, mm, s, tonne).",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run a config and write its results")
    run.add_argument("config", help="TOML run configuration")
    run.add_argument(
        "--out",
        required=True,
        help="output folder (created if needed); a folder that is not empty must be one a "
        "run wrote (it holds .fenics-adaptive-run.json): a new run removes only what that run "
        "wrote",
    )
    run.add_argument(
        "--overwrite",
        action="store_true",
        help="use a non-empty folder that is not a run folder: only this program's own result "
        "files are removed from it, never other files",
    )
    run.add_argument("--quiet", action="store_true", help="no progress and no log lines")
    run.add_argument(
        "--restart",
        metavar="CHECKPOINT",
        help="continue from this checkpoint folder (or the output folder holding one)",
    )
    check = commands.add_parser("check", help="check a config and report the time step, no run")
    check.add_argument("config", help="TOML run configuration")
    args = parser.parse_args(argv)

    comm = MPI.COMM_WORLD
    errors = comm.Dup() if comm.size > 1 else None  # for _fail only
    # Imported here so that `--help` answers without loading DOLFINx.
    from fenics_adaptive.config import load_config
    from fenics_adaptive.explicit import Interrupted
    from fenics_adaptive.runner import build_problem, run_config

    try:
        config = load_config(args.config)
        if args.command == "check":
            problem = build_problem(config, comm)
            if comm.rank == 0:
                steps = config.solver.end_time / problem.time_step
                print(
                    f"{args.config}: ok; time step {problem.time_step:.4e} s "
                    f"(stable {problem.stable_time_step:.4e} s), {steps:.0f} steps"
                )
            return 0
        run_config(
            config,
            args.out,
            comm,
            show_progress=not args.quiet,
            log=None if args.quiet else print,
            restart=args.restart,
            overwrite=args.overwrite,
        )
    except Interrupted as error:
        if comm.rank == 0:
            again = ["fenics-adaptive", "run", args.config, "--out", args.out]
            print(
                f"fenics-adaptive: {error}; continue with: "
                f"{shlex.join([*again, '--restart', args.out])}",
                file=sys.stderr,
            )
        return 130
    except InputError as error:
        return _fail(errors, 2, f"fenics-adaptive: {args.config}: {error}")
    except Exception as error:  # the run itself failed: say why in one line
        if os.environ.get("FENICS_ADAPTIVE_TRACEBACK"):
            traceback.print_exc()
        return _fail(
            errors,
            1,
            f"fenics-adaptive: run failed: {type(error).__name__}: {error} "
            "(FENICS_ADAPTIVE_TRACEBACK=1 shows where)",
        )
    return 0


AGREE_TIMEOUT = 10.0  # s: how long a failed rank waits for the others to fail too


def _fail(errors: MPI.Comm | None, status: int, line: str) -> int:
    """Print ``line`` once (rank 0) and return ``status``, when every rank has failed: errors
    are raised on every rank (a collective decision, or ``errors.shared_errors``). A rank that
    fails alone, the others not arriving here within AGREE_TIMEOUT s (they wait in a collective
    it will never enter), prints the line itself and aborts the MPI job with ``status``.

    ``errors``: a duplicate of the run's communicator (None in serial), so that this check
    never meets the run's own pending collectives."""
    comm = MPI.COMM_WORLD
    if errors is not None:
        arrived = errors.Ibarrier()
        deadline = time.monotonic() + AGREE_TIMEOUT
        while not arrived.Test():
            if time.monotonic() > deadline:
                print(f"{line} [rank {comm.rank} alone; aborting the MPI job]", file=sys.stderr)
                sys.stderr.flush()
                comm.Abort(status)
            time.sleep(0.01)
    if comm.rank == 0:
        print(line, file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
