"""The stable time step of a structure's explicit central-difference scheme: the smallest of
L_e / c over its unrefined cells and subelements and of the limit of its cohesive penalty
springs (``element.timestep`` holds the formulas).

Units: N, mm, s, tonne.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from dolfinx import la
from mpi4py import MPI

from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.element.timestep import characteristic_lengths, cohesive_pair_time_steps
from fenics_adaptive.materials.cohesive import P_KN, P_KS

if TYPE_CHECKING:
    from fenics_adaptive.model.structure import Structure


def stable_time_step(structure: Structure, current: bool = False) -> tuple[float, str]:
    """(min of L_e / c over unrefined cells and subelements, and of the cohesive pair limit;
    where it is attained), reduced over ranks. ``current``: L_e of the deformed cells and
    subelements (at X + u, for finite kinematics: a cell crushed to half its thickness steps at
    half the step), else of the reference ones. With a selectively scaled mass
    (``structure.scaled_mass``) the solid part is its element eigenvalue bound instead
    (``mass_scaling.SelectiveMass.stable_time_step``); the cohesive pairs keep their lumped
    masses (see ``mass_scaling``'s docstring: why not the scaled ones). The caller applies the
    safety factor."""
    scaled = structure.scaled_mass
    if scaled is not None:
        return _scaled_time_step(structure, scaled)
    candidates = []
    if current:
        vertices = structure.base.V.dofmap.list[: structure.base.n_owned_cells]
        deformed = structure.cell_vertices() + structure.gather(vertices, "u")
        ratios = characteristic_lengths(deformed) / structure.base.cell_wave_speeds()
    else:
        ratios = structure.base.cell_time_steps().copy()
    ratios[structure.refinement.refined_cells()] = np.inf
    eroded = structure.ply_damage_state.eroded if structure.erosion else None
    if eroded is not None:  # what erosion removed has no step
        cells = np.arange(len(ratios))
        ratios[eroded(cells, structure.cell_plies)] = np.inf
    if len(ratios):
        cell = int(np.argmin(ratios))
        candidates.append((float(ratios[cell]), f"cell {structure.original_cell[cell]}"))
    if len(structure.subelements):
        X = structure.gather(structure.subelements.nodes, "X")
        if current:
            X += structure.gather(structure.subelements.nodes, "u")
        sub_ratios = characteristic_lengths(X) / structure.subelement_speeds
        if eroded is not None:
            sub_ratios[eroded(structure.subelement_cells, structure.subelement_plies)] = np.inf
        s = int(np.argmin(sub_ratios))
        cell = structure.subelement_cells[s]
        candidates.append(
            (float(sub_ratios[s]), f"subelement of cell {structure.original_cell[cell]}")
        )
    # collective (vectors and scatters): on every rank, with or without cohesive elements;
    # it depends on the refinement alone (reference areas, masses), so a structure keeps it
    # until the next refinement (the deformed cells' step is asked for at every history row)
    candidates.append(structure.cohesive_step())
    return structure.comm.allreduce(min(candidates), op=MPI.MIN)


def _scaled_time_step(structure: Structure, scaled) -> tuple[float, str]:
    """Collective: the stable step with a scaled mass: the element bound dt_s (``SelectiveMass
    .stable_time_step``) and the cohesive pairs' dt_c combined as their eigenvalues add,
    1 / sqrt(1 / dt_s^2 + 1 / dt_c^2) (rigorous for the element bound, where the smaller of
    the two is not: the eigenvalue bound is sharp, unlike L_e / c); where: both."""
    step, cell = scaled.stable_time_step()
    solid = (step, f"cell {structure.original_cell[cell]} (scaled mass)" if cell >= 0 else "")
    solid = structure.comm.allreduce(solid, op=MPI.MIN)
    springs = cohesive_time_step(structure)
    springs = structure.comm.allreduce(springs, op=MPI.MIN)
    if not np.isfinite(springs[0]):
        return solid
    combined = 1.0 / np.sqrt(1.0 / solid[0] ** 2 + 1.0 / springs[0] ** 2)
    return float(combined), f"{springs[1]} with {solid[1]}"


def cohesive_time_step(structure: Structure) -> tuple[float, str]:
    """Penalty springs of this rank's cohesive elements against the masses they join: (the
    smallest step, where), (inf, "") without any. Collective (the nodal interface areas
    are summed over ranks), so every rank calls it, whatever it holds."""
    params = structure.cohesive.params
    stiffness = max(params[P_KN], params[P_KS])
    ab, ax = structure.interface_areas()
    lower = structure.cohesive.nodes[:, :4].ravel()
    upper = structure.cohesive.nodes[:, 4:].ravel()

    def nodal(values_base, values_extra, nodes):
        out = np.empty(len(nodes))
        is_base = nodes < structure.n_base
        out[is_base] = values_base[nodes[is_base]]
        out[~is_base] = values_extra[nodes[~is_base] - structure.n_base]
        return out

    mb = structure.mass_base.array.reshape(-1, 3)[:, 0]
    mx = structure.mass_extra.array.reshape(-1, 3)[:, 0]
    steps = cohesive_pair_time_steps(
        stiffness,
        nodal(ab, ax, lower),
        nodal(mb, mx, lower),
        nodal(mb, mx, upper),
    )
    if len(steps) == 0:
        return np.inf, ""
    k = int(np.argmin(steps))
    return float(steps[k]), f"cohesive element {k // 4} (penalty {stiffness:g} N/mm^3)"


def nodal_interface_areas(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """Each lower node's share of the area of the cohesive elements around it (mm^2), summed
    over the elements of all ranks: (base nodes (owned + ghosts), extra nodes (owned +
    ghosts)), 0 where a node holds none. Collective."""
    X = structure.gather(structure.cohesive.nodes, "X")
    areas = quad_areas(X[:, :4, :])
    area_base = la.vector(structure.mass_base.index_map, bs=3)
    area_extra = la.vector(structure.mass_extra.index_map, bs=3)
    ab, ax = area_base.array.reshape(-1, 3), area_extra.array.reshape(-1, 3)
    lower = structure.cohesive.nodes[:, :4].ravel()
    shares = np.repeat(0.25 * areas, 4)
    is_base = lower < structure.n_base
    np.add.at(ab[:, 0], lower[is_base], shares[is_base])
    np.add.at(ax[:, 0], lower[~is_base] - structure.n_base, shares[~is_base])
    for vector in (area_base, area_extra):
        vector.scatter_reverse(la.InsertMode.add)
        vector.scatter_forward()
    return ab[:, 0].copy(), ax[:, 0].copy()
