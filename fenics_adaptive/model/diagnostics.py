"""What one reads off a structure for reports and error messages, outside the structure: the
delaminated area (and its grown part), the strongly refined area, the energy its damage laws
dissipated, a DOF and a cell's maps in words.

Units: N, mm, s, tonne (areas mm^2, energies mJ).

The stored energies are the internal-force contributors' (``Structure.internal_forces``,
``InternalForces.energies``); the mass, momentum and kinetic energy are the blocks'
(``Structure.total_mass`` and its neighbours).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.parallel.reductions import summed
from fenics_adaptive.settings.kinds import InterfaceState

if TYPE_CHECKING:
    from fenics_adaptive.model.structure import Structure


def local_delaminated_areas(structure: Structure) -> np.ndarray:
    """(2,) mm^2, this rank's share of ``delaminated_areas`` (local: no communication)."""
    cohesive = structure.cohesive
    if not len(cohesive):
        return np.zeros(2)
    areas = quad_areas(structure.gather(cohesive.nodes[:, :4], "X"))
    failed = cohesive.failed()
    return np.array([areas[failed].sum(), areas[failed & ~cohesive.inserted()].sum()])


def delaminated_areas(structure: Structure) -> tuple[float, float]:
    """Collective: the area (mm^2) of the cohesive elements whose four points have failed, and
    its part that has grown (the insert films' elements left out), over all ranks."""
    total, grown = summed(structure.comm, local_delaminated_areas(structure))
    return float(total), float(grown)


def strong_area(structure: Structure) -> float:
    """Collective: the area (mm^2, bottom faces) of the cells refined strongly at one interface
    or more, over all ranks."""
    strong = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    faces = structure.X_base[structure.bottom_local[strong]]
    area = quad_areas(faces).sum() if strong.any() else 0.0
    return float(structure.comm.allreduce(float(area), op=MPI.SUM))


def insert_film_area(structure: Structure) -> float:
    """Collective: the area (mm^2) of the insert films' cohesive elements ([[delamination]]),
    over all ranks."""
    total, grown = delaminated_areas(structure)
    return total - grown


def local_damage_dissipation(structure: Structure) -> np.ndarray:
    """(4,) mJ, this rank's share of ``damage_dissipation`` (local: no communication)."""
    damage = structure.ply_damage_state
    if damage is None:
        return np.array([structure.cohesive.dissipated_energy(), 0.0, 0.0, 0.0])
    return np.array(
        [
            structure.cohesive.dissipated_energy(),
            damage.dissipated_energy(),
            damage.fibre_dissipated_energy(),
            damage.eroded_energy(),
        ]
    )


def damage_dissipation(structure: Structure) -> tuple[float, float, float, float]:
    """Collective: (cohesive, ply, the fibres' share of ply) energy (mJ) dissipated so far,
    summed from the damage laws' own increments (``cohesive_element_force_tracked``,
    ``ply_damage_update``), and the strain energy the eroded elements took with them, over all
    ranks."""
    cohesive, ply, fibre, eroded = summed(structure.comm, local_damage_dissipation(structure))
    return float(cohesive), float(ply), float(fibre), float(eroded)


def describe_dof(structure: Structure, block: int, dof: int) -> str:
    """Where owned DOF ``dof`` of block ``block`` (0: base, 1: extra nodes) is, in words (for
    error messages): the cell, the node's position (mm) and the component."""
    node, component = divmod(dof, 3)
    axis = "xyz"[component]
    if block == 0:
        x = structure.X_base[node]
        # the cells (rows) holding the node
        cells = structure.columns.cells_holding(node)
        cell = f"cell {structure.original_cell[cells[0]]}, " if len(cells) else ""
        return f"{cell}base node at ({x[0]:.4g}, {x[1]:.4g}, {x[2]:.4g}) mm, u_{axis}"
    n_interfaces = structure.interface_state.shape[1]
    _, interface, node_set = enr.key_parts(structure.extra.owned_keys[node], n_interfaces)
    x = structure.extra.vectors["X"].array.reshape(-1, 3)[node]
    return (
        f"extra node of interface {interface} (set {'AB'[node_set]}) at "
        f"({x[0]:.4g}, {x[1]:.4g}, {x[2]:.4g}) mm, u_{axis}"
    )


def cell_maps(structure: Structure, cell: int) -> str:
    """The gather/scatter maps (the paper's projection matrices, as index lists) of owned cell
    ``cell``, in words."""
    return enr.describe_cell(
        structure.interface_state[cell],
        structure.columns.cell(cell),
        structure.laminate.n_plies,
        structure.extra.index,
        structure.n_base,
    )
