"""Command line: ``fenics-adaptive run CONFIG.toml --out DIR [--restart CHECKPOINT]
[--overwrite]``, ``fenics-adaptive static CONFIG.toml --out DIR`` (the static check at the end
time, ``static_runner``), ``fenics-adaptive check CONFIG.toml``, ``fenics-adaptive demo [NAME ...]``
(the demos the package holds) and ``fenics-adaptive init CASE.toml`` (a starting config).

Exit status: 0 done, 2 bad input (one line on stderr naming the key), 1 the run failed, 3 the
installation is incomplete (``missing_runtime``), 130 the run was interrupted (SIGINT or
SIGTERM) after writing a checkpoint to continue from, or by Ctrl-C during start-up (one line:
nothing was run).

``check`` builds the model without running it and reports its size, the time step, the number
of steps (the count the run takes; refused above ``[solver] max_steps``), history rows and field
frames, and estimates of peak memory and wall time (``config.estimated_memory``,
``config.estimated_step_seconds``).
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING

from fenics_adaptive import __version__
from fenics_adaptive.errors import InputError

if TYPE_CHECKING:  # mpi4py is imported when a command runs, so that --help stays fast
    from mpi4py import MPI


EPILOG = """\
exit status:
  0    done
  1    the run failed (diverged, an element inverted, the energy balance broke, ...):
       one line on stderr; FENICS_ADAPTIVE_TRACEBACK=1 shows where
  2    bad input: one line on stderr naming the file and the key
  3    the installation is incomplete: DOLFINx, mpi4py, numba or gmsh cannot be imported
       (one line says which and how to install it)
  130  interrupted (Ctrl-C, SIGTERM): in the time loop after writing a checkpoint (the
       line says how to continue with --restart); during start-up nothing was run

documentation: README.md and docs/ of the source tree (config keys: docs/config.md,
output files: docs/outputs.md, the Python API: docs/api.md); `make docs` builds the site.
"""


def main(argv: list[str] | None = None) -> int:
    """The command line (see the module docstring); returns the exit status."""
    interrupt = _StartupInterrupt()
    try:
        return _command(argv, interrupt)
    except KeyboardInterrupt as error:
        interrupt.release()
        return _interrupted(error)
    finally:
        interrupt.release()


def _command(argv: list[str] | None, interrupt: _StartupInterrupt) -> int:
    parser = argparse.ArgumentParser(
        prog="fenics-adaptive",
        description="Explicit dynamics of laminated beams and plates with the adaptive "
        "thick-shell element (units: N, mm, s, tonne).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
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
    static = commands.add_parser(
        "static",
        help="solve the config statically at its end time (linear elastic check) and write "
        "the same result files",
    )
    static.add_argument("config", help="TOML run configuration")
    static.add_argument("--out", required=True, help="output folder, as for run")
    static.add_argument(
        "--overwrite", action="store_true", help="as for run: only this program's files go"
    )
    static.add_argument("--quiet", action="store_true", help="no log lines")
    check = commands.add_parser("check", help="check a config and report the time step, no run")
    check.add_argument("config", help="TOML run configuration")
    demo = commands.add_parser(
        "demo", help="run a demo the package holds (without NAME: list them)"
    )
    demo.add_argument("name", nargs="?", help="the demo (fenics-adaptive demo lists them)")
    demo.add_argument(
        "demo_args",
        nargs=argparse.REMAINDER,
        metavar="...",
        help="the demo's own options, e.g. --out DIR (fenics-adaptive demo NAME --help)",
    )
    init = commands.add_parser(
        "init", help="write a commented starting config (a cantilever that runs as it is)"
    )
    init.add_argument("path", metavar="CASE.toml", help="the file to write")
    init.add_argument("--force", action="store_true", help="replace the file if it exists")
    args = parser.parse_args(argv)
    if args.command == "init":
        return _init(Path(args.path), args.force)
    if args.command == "demo" and args.name is None:
        return _demo(None, [], interrupt)  # the list needs no runtime
    missing = missing_runtime()
    if missing:
        print(f"fenics-adaptive: {missing}", file=sys.stderr)
        return 3
    if args.command == "demo":
        return _demo(args.name, args.demo_args, interrupt)

    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    errors = comm.Dup() if comm.size > 1 else None  # for fail_ranks only
    # Imported here so that `--help` answers without loading DOLFINx.
    from fenics_adaptive.runner import run_config
    from fenics_adaptive.settings.config import load_config
    from fenics_adaptive.simulation import Simulation
    from fenics_adaptive.solver.explicit import Interrupted
    from fenics_adaptive.static_runner import static_config

    try:
        config = load_config(args.config)
        if args.command == "check":
            return _check(args.config, config, Simulation(config, comm=comm), comm)
        if args.command == "static":
            log = None if args.quiet else print
            static_config(config, args.out, comm, log=log, overwrite=args.overwrite)
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
            if comm.size > 1:  # (other counts too, unless a refinement's ties were acting)
                again = ["mpiexec", "-n", str(comm.size), *again]
            print(
                f"fenics-adaptive: {error}; continue with: "
                f"{shlex.join([*again, '--restart', args.out])}",
                file=sys.stderr,
            )
        return 130
    except InputError as error:
        return fail_ranks(errors, 2, _input_error_line(args.config, error))
    except Exception as error:  # the run itself failed: say why in one line
        if interrupt.fired:  # Ctrl-C killed a compiler or Gmsh under us: not a failure
            interrupt.release()
            return _interrupted(error)
        return fail_ranks(errors, 1, _failure_line(args.command, error))
    return 0


def _failure_line(what: str, error: Exception) -> str:
    """The one line of a failed ``what`` ("run", "demo tcb"); the traceback too on stderr when
    FENICS_ADAPTIVE_TRACEBACK is set."""
    if os.environ.get("FENICS_ADAPTIVE_TRACEBACK"):
        traceback.print_exc()
    return (
        f"fenics-adaptive: {what} failed: {type(error).__name__}: {error} "
        "(FENICS_ADAPTIVE_TRACEBACK=1 shows where)"
    )


# What a run imports, with what to say when it cannot: (module, name, how to get it)
_NATIVE = (
    'pip install "fenics-adaptive[native]" (Python >= 3.12), or the Docker image (docs/docker.md)'
)
_GMSH_LIBRARIES = "libglu1-mesa libxcursor1 libxft2 libxinerama1 libxrender1"
RUNTIME = (
    ("mpi4py.MPI", "mpi4py (MPI)", _NATIVE),
    ("dolfinx", "DOLFINx", _NATIVE),
    ("numba", "numba", "pip install numba (requirements/common.txt pins the version)"),
    (
        "gmsh",
        "gmsh",
        f"pip install gmsh; its wheel needs the system libraries {_GMSH_LIBRARIES} "
        f"(Debian/Ubuntu: apt-get install {_GMSH_LIBRARIES})",
    ),
)


def missing_runtime() -> str | None:
    """One line naming the first module of ``RUNTIME`` that cannot be imported, why, and how
    to install it; None when all import."""
    import importlib

    for module, name, how in RUNTIME:
        try:
            importlib.import_module(module)
        except ImportError as error:
            return f"{name} cannot be imported ({error}); install it: {how}"
    return None


def _init(path: Path, force: bool) -> int:
    """Write the starting config (``settings/case_template.toml``) to ``path``; never over a file
    unless ``force``."""
    template = Path(__file__).parent / "settings" / "case_template.toml"
    if path.is_dir():
        print(f"fenics-adaptive: init: {path} is a folder; name the file to write", file=sys.stderr)
        return 2
    if path.exists() and not force:
        print(
            f"fenics-adaptive: init: {path} exists; choose another name or add --force",
            file=sys.stderr,
        )
        return 2
    if not path.parent.is_dir():
        print(f"fenics-adaptive: init: no folder {path.parent}", file=sys.stderr)
        return 2
    path.write_text(template.read_text())
    print(f"wrote {path} (units: N, mm, s, tonne); next: fenics-adaptive check {path}")
    return 0


def _demo(name: str | None, demo_args: list[str], interrupt: _StartupInterrupt) -> int:
    """Run demo ``name`` of ``fenics_adaptive.demos`` with its own options, or list them."""
    from fenics_adaptive import demos

    if name is None:
        print("demos (fenics-adaptive demo NAME --out DIR; NAME --help for its options):")
        for known in demos.NAMES:
            print(f"  {known:20s} {demos.describe(known)}")
        return 0
    if name not in demos.NAMES:
        print(
            f"fenics-adaptive: demo: no demo {name!r}; the demos: {', '.join(demos.NAMES)}",
            file=sys.stderr,
        )
        return 2
    import importlib

    module = importlib.import_module(f"fenics_adaptive.demos.{name}")
    try:
        module.main(demo_args, prog=f"fenics-adaptive demo {name}")
    except InputError as error:
        print(f"fenics-adaptive: demo {name}: {error}", file=sys.stderr)
        return 2
    except Exception as error:
        if interrupt.fired:
            interrupt.release()
            return _interrupted(error)
        print(_failure_line(f"demo {name}", error), file=sys.stderr)
        return 1
    return 0


AGREE_TIMEOUT = 10.0  # s: how long a failed rank waits for the others to fail too
ABORT_GRACE = 1.0  # s: a rank aborting alone waits this long for mpiexec to forward its line


def fail_ranks(errors: MPI.Comm | None, status: int, line: str) -> int:
    """Print ``line`` once (rank 0) and return ``status``, when every rank has failed: errors
    are raised on every rank (a collective decision, or ``errors.shared_errors``). A rank that
    fails alone, the others not arriving here within AGREE_TIMEOUT s (they wait in a collective
    it will never enter), prints the line itself and aborts the MPI job with ``status``.

    ``errors``: a duplicate of the run's communicator (None in serial), so that this check
    never meets the run's own pending collectives."""
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if errors is not None:
        arrived = errors.Ibarrier()
        deadline = time.monotonic() + AGREE_TIMEOUT
        while not arrived.Test():
            if time.monotonic() > deadline:
                print(f"{line} [rank {comm.rank} alone; aborting the MPI job]", file=sys.stderr)
                sys.stderr.flush()
                # mpiexec forwards each rank's stderr through a pipe, and an abort kills the
                # ranks and the forwarders at once: without a pause the line may be lost
                time.sleep(ABORT_GRACE)
                comm.Abort(status)
            time.sleep(0.01)
    if comm.rank == 0:
        print(line, file=sys.stderr)
    return status


def _input_error_line(config_path: str, error: InputError) -> str:
    """The one line of a bad input: the config file, then the key and the problem (the file
    named once, also when the problem is the file itself)."""
    if error.key in (config_path, str(Path(config_path))):
        return f"fenics-adaptive: {error}"
    return f"fenics-adaptive: {config_path}: {error}"


def _check(config_path: str, config, simulation, comm) -> int:
    """``check``: the model's size, time step, step count (refused above solver.max_steps),
    output counts and estimates of memory and wall time, printed on rank 0; returns 0.

    Raises:
        InputError: a step count above ``solver.max_steps``.
    """
    from mpi4py import MPI

    from fenics_adaptive.model.diagnostics import insert_film_area
    from fenics_adaptive.settings.config import (
        ModelSize,
        check_step_count,
        estimated_memory,
        estimated_step_seconds,
        output_counts,
    )
    from fenics_adaptive.settings.kinds import ModelKind

    model, solver = simulation.structure.base, config.solver
    steps = check_step_count(solver, simulation.time_step)
    cells = comm.allreduce(model.mesh.topology.index_map(3).size_local, op=MPI.SUM)
    nodes = model.V.dofmap.index_map.size_global
    cell_layers = len(model.beam.layer_z) - 1
    size = ModelSize(cells, nodes, config.laminate.n_plies, cell_layers)  # as built
    rows, frames = output_counts(solver, simulation.time_step)
    memory = estimated_memory(size, comm.size)
    cohesive = comm.allreduce(len(simulation.structure.cohesive), op=MPI.SUM)
    wall = steps * estimated_step_seconds(size, comm.size, config.ply_damage, cohesive)
    films = insert_film_area(simulation.structure)  # collective
    if comm.rank == 0:
        refined = (
            " (unrefined; refined cells cost 3 .. 7 x more)"
            if config.kind == ModelKind.ADAPTIVE
            else ""
        )
        checkpoints = (
            f", a checkpoint every {solver.checkpoint_interval} steps"
            if solver.checkpoint_interval
            else ""
        )
        print(
            f"{config_path}: ok\n"
            f"  model: {config.kind}, {cells} cells, {nodes} nodes ({3 * nodes} DOFs), "
            f"{config.laminate.n_plies} plies, {cell_layers} cell layer(s), {comm.size} MPI "
            "rank(s)\n"
            f"  time step {simulation.time_step:.4e} s (stable "
            f"{simulation.stable_time_step:.4e} s with safety factor {solver.safety_factor}, "
            f"limited by {simulation.critical}), {steps} steps "
            f"to {solver.end_time:.4e} s (solver.max_steps = {solver.max_steps})\n"
            f"  output: {rows} history rows, {frames} field frames{checkpoints}\n"
            f"  estimate: peak memory {memory / 1e9:.3g} GB (all ranks), wall time "
            f"{_duration(wall)}{refined}{_compile_note(config)}"
        )
        from fenics_adaptive.element.rules import integration_warnings

        if films:
            print(f"  insert films: {films:.6g} mm^2 delaminated at t = 0")
        for line in integration_warnings(
            config.layer_laminates(), config.points_per_ply, config.preintegrate
        ):
            print(f"  {line}")
        for line in simulation.warnings:
            print(f"  {line}")
    return 0


def _compile_note(config) -> str:
    """What a first run adds before its time loop, when numba's cache lacks kernels."""
    from fenics_adaptive import kernels

    estimate = kernels.compile_estimate(config)
    return f", plus about {estimate:.0f} s compiling kernels first" if estimate else ""


def _duration(seconds: float) -> str:
    """A wall time for people: s, min, h or days."""
    for unit, length in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= length:
            return f"{seconds / length:.3g} {unit}"
    return f"{seconds:.2g} s"


class _StartupInterrupt:
    """SIGINT or SIGTERM before the time loop: remember it (a Ctrl-C may kill a compiler or
    Gmsh under the program, which then fails with some other error) and raise
    KeyboardInterrupt. The run puts its own handler in place for the time loop (checkpoint,
    then stop).

    A KeyboardInterrupt raised while Python runs inside a ctypes callback (numba's compiler
    calls back into Python for its cache) is printed and dropped, and start-up went on
    compiling (seen once in CI). So once fired it is raised again every ``AGAIN`` s (SIGALRM)
    until the program catches it and calls ``release``."""

    AGAIN = 0.25  # s

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.fired = False
        self.previous: dict = {}
        self.previous_alarm = None
        if threading.current_thread() is threading.main_thread():
            self.previous = {n: signal.signal(n, self._handle) for n in self.SIGNALS}
            _no_petsc_signal_handlers()

    def _handle(self, number, frame) -> None:
        self.fired = True
        if self.previous_alarm is None:
            self.previous_alarm = signal.signal(signal.SIGALRM, self._again)
            signal.setitimer(signal.ITIMER_REAL, self.AGAIN, self.AGAIN)
        raise KeyboardInterrupt

    def _again(self, number, frame) -> None:
        raise KeyboardInterrupt

    def release(self) -> None:
        """Restore the handlers (and stop raising again); idempotent."""
        if self.previous_alarm is not None:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, self.previous_alarm)
            self.previous_alarm = None
        for number, handler in self.previous.items():
            signal.signal(number, handler)
        self.previous = {}


def _no_petsc_signal_handlers() -> None:
    """PETSc, once DOLFINx starts it, puts its own handler on SIGTERM (and others), which
    prints an error block and aborts the MPI job: the program's own handlers (start-up, then
    the time loop's checkpoint) take the signals instead. PETSc reads its options from the
    environment when it starts (after this)."""
    options = os.environ.get("PETSC_OPTIONS", "")
    if "-no_signal_handler" not in options.split():
        os.environ["PETSC_OPTIONS"] = f"{options} -no_signal_handler".strip()


def _in_time_loop(error: BaseException) -> bool:
    """Whether the interrupt came once the run had entered its time loop (``runner.execute``
    sets up its signal handling, ``stop``, just before the loop)."""
    tb = error.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        if frame.f_code.co_name == "execute" and "stop" in frame.f_locals:
            return True
        tb = tb.tb_next
    return False


def _rank() -> int:
    """This process's MPI rank, without starting MPI if it has not been started."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None and mpi.Is_initialized() and not mpi.Is_finalized():
        return mpi.COMM_WORLD.rank
    for name in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK"):
        if os.environ.get(name, "").isdigit():
            return int(os.environ[name])
    return 0


def _interrupted(error: BaseException) -> int:
    """One line for a Ctrl-C that the run's own handling did not turn into a checkpoint;
    exit status 130."""
    if _rank() == 0:
        if _in_time_loop(error):
            line = "interrupted at once (a second signal): no checkpoint; the results are partial"
        else:
            line = "interrupted during start-up; nothing was run"
        print(f"fenics-adaptive: {line}", file=sys.stderr)
    return 130


if __name__ == "__main__":
    sys.exit(main())
