"""Measured cost: wall time of a call or of an explicit step, compilation kept out.

Every figure is a statistic (``min``, as ``timeit`` takes: other load on the machine only ever
adds time; or ``statistics.median``) of several timed repetitions after warm-up calls, so numba
and FFCx compile once, outside the timing. The demos and ``benchmarks/run.py`` all measure
through these two functions.

Units: seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.kinds import MassScaling
from fenics_adaptive.settings.solver import Probe, SolverSettings
from fenics_adaptive.solver import explicit

Statistic = Callable[[Sequence[float]], float]


def time_call(
    call: Callable[[], object], repeats: int, warmups: int = 1, statistic: Statistic = min
) -> tuple[float, float]:
    """(statistic of ``repeats`` timed calls after ``warmups`` untimed ones, seconds of the
    first warm-up call: with numba or FFCx compiling, the compile time shows in it)."""
    first = 0.0
    for k in range(warmups):
        start = time.perf_counter()
        call()
        if k == 0:
            first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return float(statistic(times)), first


def time_per_step(
    structure: Structure,
    probe: Probe,
    steps: int = 200,
    repeats: int = 3,
    statistic: Statistic = min,
    mass_scaling: MassScaling = MassScaling.NONE,
) -> tuple[float, float]:
    """(wall time of one explicit step (s), the stable time step used (s)): the statistic of
    ``repeats`` runs of ``steps`` central-difference steps at the stable step from rest, each
    timed by the solver itself (its clock starts after set-up) and divided by its steps; a
    short run first compiles everything (and builds a scaled mass, ``mass_scaling``). The
    structure's displacement is overwritten."""
    once = SolverSettings(end_time=1.0, output_interval=1.0, mass_scaling=mass_scaling)
    explicit.prepare_mass(structure, once, refines=False)
    dt, _, _ = explicit.choose_time_step(structure, once)
    warm = SolverSettings(end_time=5 * dt, output_interval=5 * dt, mass_scaling=mass_scaling)
    explicit.run(structure, warm, probe)
    settings = SolverSettings(
        end_time=steps * dt, output_interval=steps * dt, mass_scaling=mass_scaling
    )
    per_step = []
    for _ in range(repeats):
        stats = explicit.run(structure, settings, probe)
        per_step.append(stats.wall_time / max(stats.steps, 1))
    return float(statistic(per_step)), float(dt)
