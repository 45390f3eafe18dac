"""A model of an explicit step's wall time on many MPI ranks, with constants measured here.

Units: s, bytes, cells; a plate of nx x ny cells in plane (one cell through the thickness in
ESL and adaptive models, one per sublaminate in layerwise ones).

On P ranks the slowest rank sets the step:

    T(P) = t_cell * max_r W_r                                     (compute)
         + s * (o + n_nb * alpha + 8 * V / beta)                  (the step's halo exchanges)
         + (R / k) * 2 * ceil(log2 P) * alpha                     (reductions of output steps)
         - min(n_nb * alpha + 8 * V / beta, t_cell * W_interior)  (hidden by the overlap)

with W_r the work of rank r in unrefined-cell equivalents (a refined cell costs ``w`` of them),
s the exchanges a step waits for (two: ``benchmarks/sync_points.py`` counts them), o the
per-exchange cost on a rank (packing, unpacking, the call: measured here), n_nb the neighbours of
a rank, alpha the latency of one message, V the values a rank sends and receives per exchange
(3 per boundary node, 8 bytes each), beta the bandwidth per rank, and R reductions every k
steps (the history rows; an allreduce takes about 2 log2 P message latencies). The first
exchange of a step (the displacements) travels while the rank computes its interior cells
(``ExplicitSolver.overlap``): its latency and transfer are hidden up to that work
(``benchmarks/overlap_trace.py`` shows it on two ranks); its packing and unpacking are not.

The partition is modelled as the grid of px x py patches with the shortest cuts (``patch_grid``,
near-square on a square plate): the one
the layered meshes' own partitioner makes (``meshes.beam.columnar_partitioner``) and the one
DOLFINx's graph partitioner approaches on a single-layer plate. ``ghost_nodes`` gives the ghost
nodes it makes, which ``tests/test_scaling_model.py`` holds against the partitions of plates on
2, 4 and 8 ranks. The refined cells of an impact are a disc about the impact point
(``disc_work``): with equal cells per rank the ranks whose patches cover it carry them all, so
the model gives both that partition and one weighted by cost (every rank the mean work).

``docs/parallel.md`` shows the model's strong and weak scaling (``benchmarks/scaling_model.py``
measures the constants and draws them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fenics_adaptive.meshes.beam import patch_grid

__all__ = [
    "Interconnect",
    "StepConstants",
    "disc_work",
    "ghost_nodes",
    "patch_grid",
    "step_time",
]


@dataclass(frozen=True)
class Interconnect:
    """What the machine's network does per message: ``latency`` (s) and ``bandwidth`` (bytes/s
    per rank). The defaults are of the order of a current cluster's (InfiniBand, MPI): they are
    parameters of the model, not measured here (two shared vCPUs have no network)."""

    latency: float = 2e-6
    bandwidth: float = 10e9


@dataclass(frozen=True)
class StepConstants:
    """The constants measured on this machine (``benchmarks/scaling_model.py``).

    ``cell_step``: s per unrefined cell per step (the whole step's share of it, at a size
    where the fixed costs do not count); ``refined_cost``: what a refined cell costs in
    unrefined cells; ``exchange_overhead``: s per halo exchange on a rank (packing, unpacking,
    the MPI call, without waiting); ``exchanges``: halo exchanges a step waits for;
    ``node_layers``: node layers through the thickness (2 in an ESL plate; an adaptive plate's
    refined cells add theirs through ``refined_layers``, extra node layers per refined
    column); ``reductions``, ``output_every``: allreduce calls of an output step, and steps
    between output steps."""

    cell_step: float
    refined_cost: float
    exchange_overhead: float
    exchanges: int = 2
    node_layers: int = 2
    refined_layers: float = 0.0
    reductions: int = 10
    output_every: int = 100


def ghost_nodes(nx: int, ny: int, ranks: int, layers: int = 2) -> tuple[float, float]:
    """(mean, largest) ghost nodes per rank of an nx x ny plate of ``layers`` node layers cut
    into the patch grid of ``ranks``: a node on a cut between two patches is a ghost on one of
    them, a node where four patches meet on three. Largest: an inner patch's, half its
    boundary nodes (its share of the cuts it touches)."""
    if ranks == 1:
        return 0.0, 0.0
    px, py = patch_grid(ranks, nx, ny)
    if px > nx or py > ny:
        raise ValueError(f"{ranks} ranks cannot cut a {nx} x {ny} plate into patches")
    on_cuts = (px - 1) * (ny + 1) + (py - 1) * (nx + 1)  # nodes on a cut, a crossing twice
    crossings = (px - 1) * (py - 1)  # counted twice above; shared by four: three ghosts
    total = layers * (on_cuts - 2 * crossings + 3 * crossings)
    a, b = nx / px, ny / py
    cuts = min(px - 1, 2) * (b + 1) + min(py - 1, 2) * (a + 1)  # an inner patch's cut nodes
    return total / ranks, 0.5 * layers * cuts


def neighbours(ranks: int, nx: int, ny: int) -> int:
    """Neighbours of an inner patch of the grid of an nx x ny plate (across its sides and its
    corners)."""
    if ranks == 1:
        return 0
    px, py = patch_grid(ranks, nx, ny)
    return (3 if px > 1 else 1) * (3 if py > 1 else 1) - 1


def disc_work(
    nx: int, ny: int, ranks: int, refined_share: float, refined_cost: float
) -> tuple[float, float]:
    """(mean, largest) work per rank in unrefined-cell equivalents of an nx x ny plate whose
    refined cells (``refined_share`` of them, each costing ``refined_cost``) form a disc about
    its centre, cut into the patch grid of ``ranks`` with equal cells per patch."""
    px, py = patch_grid(ranks, nx, ny)
    x = (np.arange(nx) + 0.5) / nx - 0.5
    y = (np.arange(ny) + 0.5) / ny - 0.5
    radius2 = refined_share / math.pi  # the disc's area is the refined share of the unit plate
    refined = (x[:, None] ** 2 + y[None, :] ** 2) <= radius2
    work = np.where(refined, refined_cost, 1.0)
    # patch sums: cumulative sums at the cuts (the patches hold equal cells, within one row)
    cuts_x = np.round(np.linspace(0, nx, px + 1)).astype(int)
    cuts_y = np.round(np.linspace(0, ny, py + 1)).astype(int)
    per_column = np.add.reduceat(work, cuts_x[:-1], axis=0)
    per_patch = np.add.reduceat(per_column, cuts_y[:-1], axis=1)
    return float(per_patch.mean()), float(per_patch.max())


def step_time(
    constants: StepConstants,
    network: Interconnect,
    nx: int,
    ny: int,
    ranks: int,
    refined_share: float = 0.0,
    balanced: bool = False,
    overlap: bool = True,
) -> dict[str, float]:
    """The model's step time (s) of an nx x ny plate on ``ranks`` ranks and its parts
    (``compute``, ``latency``, ``transfer``, ``output``, less ``hidden``; ``total``).
    ``refined_share``: the share of refined cells (a disc about the plate's centre);
    ``balanced``: the partition weighted by cost (every rank the mean work) instead of equal
    cells per rank; ``overlap``: the displacements' exchange travels while the interior cells
    compute (all but the cells along the cuts)."""
    mean, largest = disc_work(nx, ny, ranks, refined_share, constants.refined_cost)
    compute = constants.cell_step * (mean if balanced else largest)
    layers = constants.node_layers + refined_share * constants.refined_layers
    _, ghosts = ghost_nodes(nx, ny, ranks, 1)
    values = 3 * 2 * ghosts * layers  # sent and received: both sides of the cuts it touches
    if ranks == 1:
        latency = transfer = output = hidden = 0.0
    else:
        latency = constants.exchanges * (
            constants.exchange_overhead + neighbours(ranks, nx, ny) * network.latency
        )
        transfer = constants.exchanges * 8.0 * values / network.bandwidth
        tree = 2 * math.ceil(math.log2(ranks)) * network.latency
        output = constants.reductions * tree / constants.output_every
        in_flight = neighbours(ranks, nx, ny) * network.latency + 8.0 * values / network.bandwidth
        # the interior: the rank's cells but a row along each cut it touches
        boundary_cells = ghosts
        interior = compute * max(1.0 - boundary_cells * ranks / (nx * ny), 0.0)
        hidden = min(in_flight, interior) if overlap else 0.0
    total = compute + latency + transfer + output - hidden
    return {
        "compute": compute,
        "latency": latency,
        "transfer": transfer,
        "output": output,
        "hidden": hidden,
        "total": total,
    }
