"""What a step costs on each rank: the cost of a cell, the imbalance of a partition.

Units: cost in unrefined cells per step (a rank's step takes about ``t_cell`` times its cost:
``parallel.scaling``).

A refined cell costs more than an unrefined one: its subelements, cohesive elements and extra
nodes. About 1 + ``REFINED_INTERFACE_COST`` per interface it is refined at: measured, a cell
refined at three interfaces costs 6.8 unrefined ones in the TCB beam (``benchmarks/run.py``,
``step`` rows) and 8.7 in the impact plate (``benchmarks/scaling_model.py``), 1.9 and 2.6 per
interface; 2.3 is their mean. A partition needs the ratios to some ten per cent, not exactly.

The partition is cut when the mesh is made (``meshes.beam.columnar_partitioner``): with
``[mesh] partition = "cost"`` (the default) an adaptive model's cells under an insert film,
refined from the start, weigh what they cost (``film_cost``) and every rank gets the same cost.
A run reports its imbalance, the most expensive rank's cost over the mean (1 when balanced),
at the start, after each refinement and at its largest (``summary.json``: "load_balance").
A front that grows into one rank's patch makes that rank the slowest: past ``[mesh]
rebalance`` the run cuts its partition again, each cell weighed as refined then
(``refined_cost``), and continues there from a checkpoint (``runner.execute``,
``parallel.redistribute``; ``benchmarks/balance.py`` measures both on the demos).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from mpi4py import MPI

# unrefined cells per interface a cell is refined at (weak or strong), on top of its own 1
REFINED_INTERFACE_COST = 2.3


def cell_costs(refined_interfaces: np.ndarray) -> np.ndarray:
    """(n,) cost of cells refined at ``refined_interfaces`` (n,) interfaces each."""
    return 1.0 + REFINED_INTERFACE_COST * np.asarray(refined_interfaces, dtype=np.float64)


def film_cost(
    films: Sequence, front: np.ndarray | None = None
) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """``cost(x, y)`` (mm) of the cells of an adaptive model under the insert films ``films``
    (``settings.adaptivity.Delamination``: refined strongly at their interfaces from the
    start), and within ``front[i - 1]`` mm of a film at interface i (the band the front
    indicator refines ahead of it at t = 0: ``indicators.front_distances``; a box about the
    film); None without films (every cell costs the same)."""
    films = list(films)
    if not films:
        return None

    def cost(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        interfaces = sorted({film.interface for film in films})
        refined = np.zeros(len(x))
        for interface in interfaces:
            reach = float(front[interface - 1]) if front is not None else 0.0
            near = np.zeros(len(x), dtype=bool)
            for film in films:
                if film.interface == interface:
                    r = film.region
                    near |= (
                        (x >= r.x_min - reach)
                        & (x <= r.x_max + reach)
                        & (y >= r.y_min - reach)
                        & (y <= r.y_max + reach)
                    )
            refined += near
        return cell_costs(refined)

    return cost


def refined_cost(
    centroids: np.ndarray, refined_interfaces: np.ndarray, cell_size: float
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``cost(x, y)`` (mm) of the cells with in-plane centroids ``centroids`` (n, 2) mm refined
    at ``refined_interfaces`` (n,) interfaces each, the others unrefined: what a partition
    re-balanced after refinement weighs. ``cell_size``: mm, the centroids are matched to a
    thousandth of it."""
    tol = 1e-3 * cell_size
    keys = np.round(np.asarray(centroids, dtype=float).reshape(-1, 2) / tol).astype(np.int64)
    table = dict(zip(map(tuple, keys.tolist()), np.asarray(refined_interfaces).tolist(),
                     strict=True))  # fmt: skip

    def cost(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        at = np.round(np.stack([x, y], axis=1) / tol).astype(np.int64).tolist()
        return cell_costs(np.array([table.get(tuple(k), 0) for k in at], dtype=float))

    return cost


def structure_costs(interface_state: np.ndarray) -> np.ndarray:
    """(n,) cost of the cells whose interfaces are in ``interface_state`` (n, interfaces:
    ``InterfaceState`` values, 0 unrefined)."""
    return cell_costs(np.count_nonzero(np.asarray(interface_state) > 0, axis=1))


def imbalance(comm: MPI.Comm, local_cost: float) -> float:
    """Collective: the largest rank's cost over the mean cost of the ranks (1 on one rank or
    when nothing costs)."""
    costs = np.empty(comm.size)
    comm.Allgather(np.array([float(local_cost)]), costs)
    mean = costs.mean()
    return float(costs.max() / mean) if mean > 0 else 1.0
