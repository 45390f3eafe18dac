"""The numba kernels, compiled before a run's time loop rather than inside it.

Every per-element loop of the package is a numba function compiled on its first call and kept
in numba's disk cache (``cache=True``). On a machine where the cache is empty (a fresh install,
or after an upgrade changed the source) a run would otherwise compile them inside its time loop,
at its first refinement: some 30-45 s unannounced, counted in the time per step, and deaf to
Ctrl-C, since the loop's signal handler only asks for a stop at the next poll.

``prepare`` checks the cache first. When a kernel a run of its variant (with or without ply
damage) may call is missing there, it says so in one line and runs ``WARM_UP``, a model of six
cells that reaches every such kernel (strong and weak refinements, cohesive elements, the border
between refined and unrefined cells, the refinement indicators, an impactor, the run's guards,
ply damage or finite kinematics) for a few steps, before the run's time loop: still start-up, so
Ctrl-C stops it at once, and the run's timings never include it. Measured on an empty cache
(2 vCPUs, AMD EPYC, one run at a time): 84 s for the elastic variant, 87 s with ply damage (206
s before the damaged element kernel was split into separately compiled functions; 31 and 44 s
when the kernels were fewer, on a faster machine). With a warm cache it costs a look
at the cache's index files (milliseconds).
"""

from __future__ import annotations

import copy
import hashlib
import importlib
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from mpi4py import MPI

# the modules that define numba kernels (tests/test_kernels.py checks the list is complete)
KERNEL_MODULES = (
    "fenics_adaptive.adaptivity.indicators",
    "fenics_adaptive.adaptivity.interlaminar",
    "fenics_adaptive.adaptivity.ply_fields",
    "fenics_adaptive.adaptivity.stabilisation",
    "fenics_adaptive.element.assumed_strain",
    "fenics_adaptive.element.batched",
    "fenics_adaptive.element.subelement",
    "fenics_adaptive.element.timestep",
    "fenics_adaptive.materials.cohesive",
    "fenics_adaptive.materials.ply_damage",
    "fenics_adaptive.model.assembly",
    "fenics_adaptive.model.border",
    "fenics_adaptive.model.contact",
    "fenics_adaptive.model.forms",
    "fenics_adaptive.model.mass_scaling",  # not in the warm-up: compiled as it is built
    "fenics_adaptive.parallel.halo",  # not in the warm-up (one rank): compiled as it is built
    "fenics_adaptive.parallel.reductions",
    "fenics_adaptive.solver.blocks",
    "fenics_adaptive.solver.guards",
)
# s to compile the kernels of each variant (``compile_all`` on an empty cache) on the slower of
# this project's 2-vCPU machines (first runs of tests/data configs with an empty NUMBA_CACHE_DIR,
# 2026-12-08); the notice scales it by the share of kernels missing
COLD_SECONDS = {"elastic": 85.0, "ply_damage": 90.0}
STAMP = "fenics_adaptive-kernels.json"


def kernels() -> dict[str, object]:
    """Every numba kernel of the package: "module.function" -> its dispatcher."""
    from numba.core.registry import CPUDispatcher

    found = {}
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for attribute, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == name:
                found[f"{name.rsplit('.', 1)[1]}.{attribute}"] = value
    return found


def is_cached(dispatcher) -> bool:
    """Whether numba's disk cache holds a compiled version of ``dispatcher`` for its current
    source. Reads numba's cache index the way numba itself does before it compiles; anything
    unexpected there (another numba version) counts as not cached."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:
        return False


def _stamp_path() -> Path:
    """The warm-up's record, next to numba's cache of the element kernels."""
    from fenics_adaptive.element import subelement

    return Path(subelement.solid_shell_forces._cache._cache_path) / STAMP


def _sources() -> str:
    """What the compiled kernels depend on: numba's and Python's versions and the kernel
    modules' sources."""
    import numba

    digest = hashlib.sha256(f"{numba.__version__} {sys.version}".encode())
    for name in KERNEL_MODULES:
        digest.update(Path(importlib.import_module(name).__file__).read_bytes())
    return digest.hexdigest()


def missing(variant: str) -> list[str]:
    """The kernels a run of ``variant`` (``VARIANTS``) may still have to compile: none when the
    warm-up of that variant was made from the present sources and every kernel it left in the
    disk cache is still there; otherwise those gone from the cache, or all of them (names as in
    ``kernels``).

    Kernels that numba inlines into others and never caches on their own do not count: the
    warm-up's record lists the ones it found cached."""
    found = kernels()
    cached = _recorded_variants(_sources()).get(variant)
    if not isinstance(cached, list):
        return list(found)
    return [name for name in cached if not is_cached(found.get(name))]


def _recorded_variants(sources: str) -> dict:
    """The warm-up record's kernels by variant, if it was made from ``sources`` (``_sources``);
    empty for a missing, unreadable or outdated record."""
    try:
        record = json.loads(_stamp_path().read_text())
    except (OSError, ValueError, AttributeError):
        return {}
    if not isinstance(record, dict) or record.get("sources") != sources:
        return {}
    variants = record.get("variants")
    return variants if isinstance(variants, dict) else {}


def _record_warm_up(variant: str) -> None:
    """After ``compile_all(variant)``: which kernels are cached now, for ``missing``."""
    cached = [name for name, dispatcher in kernels().items() if is_cached(dispatcher)]
    path = _stamp_path()
    sources = _sources()
    variants = _recorded_variants(sources)
    variants[variant] = cached
    partial = path.with_suffix(".partial")
    try:
        partial.write_text(json.dumps({"sources": sources, "variants": variants}, indent=1))
        os.replace(partial, path)
    except OSError:
        pass  # an unwritable cache: numba warns about it; every run then compiles again


# A model that reaches every kernel a run of its variant calls, in a few steps: 6 cells of 4
# plies, interface 2 strong in the first two cells and interface 1 weak in the first from t = 0
# (subelements, cohesive elements, the border to the unrefined cells, the ties of the strong
# pairs), the indicators at every step, a sphere 0.01 mm above the top face. Units: N, mm, s,
# tonne.
WARM_UP = {
    "model": {"kind": "adaptive"},
    "mesh": {"length": 3.0, "width": 0.5, "nx": 6, "ny": 1},
    "materials": {
        "ply": {
            "E1": 171420.0, "E2": 9080.0, "G12": 5290.0, "nu12": 0.32, "nu23": 0.5,
            "rho": 1.59e-9,
            "failure": {"XT": 2326.2, "XC": 1200.1, "YT": 62.3, "YC": 199.8, "S12": 92.3,
                        "G2c": 0.277, "G6c": 0.788},
        }
    },
    "laminate": {"material": "ply", "ply_thickness": 0.25, "angles": [0, 90, 90, 0]},
    "interfaces": {"delaminate": [2], "refine": [1]},
    "cohesive": {"K_n": 1.0e5, "K_s": 1.0e5, "N": 62.3, "S": 92.3, "GIc": 0.277,
                 "GIIc": 0.788, "law": "bk", "exponent": 2.1},
    "refinement": [
        {"time": 0.0, "interfaces": [2], "kind": "strong", "x_max": 1.0},
        {"time": 0.0, "interfaces": [1], "kind": "weak", "x_max": 0.5},
    ],
    "indicators": {"interval": 1.0e-9, "ply_failure": 1.0, "interface_stress": 0.9},
    "stabilisation": {"release_window": 1.0e-7},
    "impactor": {"shape": "sphere", "radius": 2.0, "mass": 1.0e-6,
                 "position": [1.5, 0.25, 3.01], "velocity": [0.0, 0.0, -1000.0]},
    "clamp": [{"face": "x0"}],
    "solver": {"end_time": 4.0e-7},
    "output": {"interval": 4.0e-7, "displacement_face": "top", "reaction_face": "x0",
               "component": "z"},
}  # fmt: skip
# The two kinds of run: the solid kernels with ply damage are others than the elastic ones.
VARIANTS = ("elastic", "ply_damage")


def variant_of(config) -> str:
    """The ``VARIANTS`` entry of a ``RunConfig``."""
    return "ply_damage" if config.ply_damage else "elastic"


def warm_up_config(variant: str) -> dict:
    """``WARM_UP`` for ``variant``: with ply damage (and the matrix-damage indicator), or
    elastic with finite kinematics (the switch is an argument of the same kernels)."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS} (got {variant!r})")
    data = copy.deepcopy(WARM_UP)
    if variant == "ply_damage":
        data["model"]["ply_damage"] = True
        data["indicators"]["matrix_damage"] = True
    else:
        data["model"]["kinematics"] = "finite"
    return data


@contextmanager
def compilations() -> Iterator[list[str]]:
    """The numba functions compiled (not loaded from the disk cache) while the block runs, as
    "module.function" names in the order numba compiled them: what a time loop inside it did
    compile although ``prepare`` ran before it (the run's summary lists them, and a test checks
    a first run's list is empty, which its wall time could only hint at on a loaded machine)."""
    from numba.core import event

    compiled: list[str] = []

    class _Recorder(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            function = getattr(ev.data["dispatcher"], "py_func", None)  # (lifted loops: none)
            name = getattr(function, "__qualname__", repr(ev.data["dispatcher"]))
            compiled.append(f"{getattr(function, '__module__', '?')}.{name}")

        def on_end(self, ev: event.Event) -> None:
            pass

    with event.install_listener("numba:compile", _Recorder()):
        yield compiled


def compile_all(variant: str) -> None:
    """Compile (or load from the cache) every kernel a run of ``variant`` calls by running
    its warm-up model on this process alone (on ``MPI.COMM_SELF``)."""
    from fenics_adaptive.io.output import written_ply_stresses
    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import Simulation

    config = parse_config(warm_up_config(variant), source=f"<kernel warm-up, {variant}>")
    simulation = Simulation(config, comm=MPI.COMM_SELF)
    simulation.run()
    # what the field output computes in a run's loop and the warm-up's run (no output) does not
    written_ply_stresses(simulation.structure)


def compile_estimate(config) -> float:
    """Seconds a run of ``config`` (a ``RunConfig``) will spend compiling kernels before its
    time loop: 0 with a warm cache, else ``COLD_SECONDS`` of its variant times the share of
    kernels missing (this process's view of the cache)."""
    variant = variant_of(config)
    return COLD_SECONDS[variant] * len(missing(variant)) / len(kernels())


def prepare(config, comm: MPI.Comm, say: Callable[[str], None] = print) -> float:
    """Collective: make sure every kernel a run of ``config`` (a ``RunConfig``) calls is
    compiled and cached before its time loop. Rank 0 checks the cache; if it lacks any kernel,
    rank 0 says so in one line through ``say`` and compiles them (``compile_all``) while the
    other ranks wait, so that no two processes write one cache file. Returns the seconds spent
    compiling (0 when the cache was warm)."""
    variant = variant_of(config)
    estimate = comm.bcast(compile_estimate(config) if comm.rank == 0 else None, root=0)
    if not estimate:
        return 0.0
    if comm.rank == 0:
        say(
            f"compiling the numba kernels (first run only, about {estimate:.0f} s; Ctrl-C stops it)"
        )
    start = time.perf_counter()
    failure = None
    if comm.rank == 0:
        try:
            compile_all(variant)
            _record_warm_up(variant)
        except Exception as error:  # a bug here; the run would fail the same way
            failure = error
    failed = comm.bcast(failure is not None, root=0)  # also the barrier the ranks wait at
    if failure is not None:
        raise failure
    if failed:
        raise RuntimeError("compiling the numba kernels failed on rank 0")
    return time.perf_counter() - start
