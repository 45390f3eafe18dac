"""The structure's internal forces as force contributors (``model.forces``, kind INTERNAL).

Units: N, mm, s, tonne (energies mJ = N mm).

Paper Eq. (3): f_int = f(unrefined cells) + sum_i P_i^T f^sublam_i - sum_j P_j^T f^coh_j.
Each kind of element is one contributor:

- ``ElasticSolid`` ("solid"): every solid (sub)element, the unrefined cells (ESL cells, the
  cells of a layerwise model) and the refined cells' subelements alike, through the batched
  numba kernel; the paper's first term is the UFL form of the unrefined cells, which that kernel
  equals to round-off (``tests/test_subelement.py``) at a third of its cost, and which the
  base model keeps for its linearisation (static solves);
- ``DamagedSolid`` ("ply"): with ply damage, every solid (sub)element instead, through the
  damage-aware numba kernel (the same for ESL, adaptive and layerwise cells); its state is the
  ply damage;
- ``CohesiveElements`` ("cohesive"): the cohesive elements of the strong interfaces (or of a
  layerwise model), numba; their state is the cohesive damage.

``InternalForces`` is the structure's list of them (solid first, the cohesive elements last, the
order of summation) and their stored energies summed over ranks. Which solid contributors a
structure has is decided once, when it is built (``InternalForces.of``); after a refinement
each rebuilds what depends on the cells (``refined``). The element kernels read the node
arrays of ``NodeArrays``, views the structure refreshes when its extra nodes change, so a step
allocates nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from dolfinx import la
from mpi4py import MPI

from fenics_adaptive.adaptivity.enrichment import ExtraNodes
from fenics_adaptive.adaptivity.refinement import RefinementState
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces, chunk_bounds
from fenics_adaptive.model.forces import Contributor, ForceKind
from fenics_adaptive.model.forms import LayeredModel
from fenics_adaptive.model.ply_damage_state import PlyDamageState
from fenics_adaptive.model.refined_cells import RefinedCells
from fenics_adaptive.parallel.redistribute import Rows
from fenics_adaptive.parallel.reductions import summed


@dataclass
class NodeArrays:
    """The (n, 3) arrays the element kernels read (mm): reference positions and displacements
    of the base nodes (owned + ghosts) and of the extra nodes (owned + ghosts). Views into the
    structure's vectors; ``refresh`` after the extra nodes changed (their vectors are new).

    ``ready`` (bool, one per combined local node: base nodes, then extra nodes): the nodes whose
    displacement a rank knows as soon as it has moved its own, before the halo exchange brings
    the ghosts' (owned, and not bound to masters by the border of a refined region: those
    follow their masters after the exchange). An element of ready nodes only is *interior*: the
    solver computes it while the exchange is under way (``Contributor.add_interior_force``).
    On one rank every node is ready. Set by the structure (``mark_ready``) whenever its nodes
    or border change; ``generation`` counts the changes, for the contributors that split their
    elements by it."""

    X_base: np.ndarray
    u_base: np.ndarray
    X_extra: np.ndarray
    u_extra: np.ndarray
    ready: np.ndarray | None = None
    generation: int = 0

    @classmethod
    def of(cls, X_base: np.ndarray, u_base: la.Vector, extra: ExtraNodes) -> NodeArrays:
        arrays = cls(X_base, u_base.array.reshape(-1, 3), X_base[:0], X_base[:0])
        arrays.refresh(extra)
        return arrays

    def mark_ready(
        self, n_owned_base: int, n_owned_extra: int, constrained: np.ndarray, exchanged: bool
    ) -> None:
        """``ready`` for ``n_owned_base`` owned base nodes and ``n_owned_extra`` owned extra
        nodes (each block: owned first, then ghosts), the ``constrained`` extra nodes (combined
        local indices) not ready; ``exchanged`` False (one rank): all ready."""
        n_base, n_extra = len(self.X_base), len(self.X_extra)
        ready = np.ones(n_base + n_extra, dtype=bool)
        if exchanged:
            ready[n_owned_base:n_base] = False
            ready[n_base + n_owned_extra :] = False
            ready[np.asarray(constrained, dtype=np.int64)] = False
        if self.ready is not None and np.array_equal(ready, self.ready):
            return  # (the contributors' splits stand)
        self.ready = ready
        self.generation += 1

    def interior(self, element_nodes: np.ndarray) -> np.ndarray:
        """(n,) bool: which elements of ``element_nodes`` (n, k combined local indices) have
        ready nodes only; none while ``ready`` is not known (the safe side: all computed after
        the exchange)."""
        if self.ready is None or len(element_nodes) == 0:
            return np.zeros(len(element_nodes), dtype=bool)
        return self.ready[element_nodes].all(axis=1)

    def refresh(self, extra: ExtraNodes) -> None:
        """Views of the extra nodes' current vectors; ``ready`` unknown until ``mark_ready``."""
        self.X_extra = extra.vectors["X"].array.reshape(-1, 3)
        self.u_extra = extra.vectors["u"].array.reshape(-1, 3)
        self.ready = None
        self.generation += 1

    def kernel_arguments(self, f_base: np.ndarray, f_extra: np.ndarray) -> tuple[np.ndarray, ...]:
        """(X_base, X_extra, u_base, u_extra, f_base, f_extra), all (n, 3): the node arguments
        of the element kernels, with the flat force arrays ``f_base``, ``f_extra`` as views."""
        return (
            self.X_base,
            self.X_extra,
            self.u_base,
            self.u_extra,
            f_base.reshape(-1, 3),
            f_extra.reshape(-1, 3),
        )


class ElasticSolid(Contributor):
    """Every solid (sub)element of the structure through the batched elastic kernel
    (``element.batched``): unrefined cells whole (all plies, or an LW layer's), refined cells by
    subelement, with the base model's kinematics (read per call, so that
    ``LayeredModel.set_kinematics`` switches it with the forms).

    The base model's UFL form is not assembled in a step; it keeps integrating the unrefined
    cells (``refined``) for ``solver.static`` (a linear static solve of the base model's cells,
    which differentiates the form). The static solver of whole structures and the stiffness
    probes (``solver.equilibrium``, ``analysis.comparison``) use this contributor's forces.
    The base model's ``selective = False`` (the fully integrated hexahedron, a UFL-only
    variant kept to show what the selective rule buys) is refused: the kernel's rules are
    selective.

    ``model``: the base model; ``refinement``: the interface states (their unrefined cells go
    to the form); ``rule_table``: the packed rules; ``nodes``: the node arrays; ``elements()``:
    the structure's solid elements now (``Structure.elements``), taken again after each
    refinement."""

    name = "solid"
    kind = ForceKind.INTERNAL

    def __init__(
        self,
        model: LayeredModel,
        refinement: RefinementState,
        rule_table: RuleTable,
        nodes: NodeArrays,
        elements: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]],
    ):
        self.model = model
        self.refinement = refinement
        self.rule_table = rule_table
        self.nodes = nodes
        self.elements = elements
        self._energy = self._interior_energy = 0.0
        if not model.selective:
            raise ValueError(
                "a structure's solids use the selective rule: selective=False is a UFL-form-only "
                "variant of the base model (build_model), for static solves of it"
            )
        self._take_elements()

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add the elements' forces (N) into the local base and extra DOFs."""
        self._energy = self._add(f_base, f_extra, self.solids.order)

    def add_interior_force(
        self, t: float, f_base: np.ndarray, f_extra: np.ndarray, progress: Callable[[], None]
    ) -> None:
        """``add_force`` of the interior elements only (``NodeArrays.interior``), in chunks
        of ``assembly.INTERIOR_CHUNK`` with a ``progress()`` after each."""
        if self._generation != self.nodes.generation:  # the ready nodes changed
            self._take_elements()
        energy = 0.0
        for chunk in self._interior_chunks:
            energy += self._add(f_base, f_extra, chunk)
            progress()
        self._interior_energy = energy

    def add_boundary_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """``add_force`` of the elements ``add_interior_force`` left."""
        boundary = self._add(f_base, f_extra, self.solids.boundary_order)
        self._energy = self._interior_energy + boundary

    def _add(self, f_base: np.ndarray, f_extra: np.ndarray, order: np.ndarray) -> float:
        return add_subelement_forces(
            self.solids, *self.nodes.kernel_arguments(f_base, f_extra), self.model.finite, order
        )

    def energy(self) -> float:
        """Strain energy (mJ) of this rank's elements at the last ``add_force``."""
        return self._energy

    def refined(self) -> None:
        """The kernel computes the structure's elements of now; the form, its unrefined cells."""
        self._take_elements()
        self.model.set_ufl_cells([self.refinement.unrefined_cells()], defer=True)

    def _take_elements(self) -> None:
        nodes, cells, plies = self.elements()
        self._generation = self.nodes.generation
        self.solids = SubelementSet(
            nodes,
            self.rule_table.rule_of(plies),
            self.rule_table.packed,
            self.nodes.interior(nodes),
            self.model.element_frames(cells),
        )
        order = self.solids.interior_order
        self._interior_chunks = [order[a:b] for a, b in chunk_bounds(len(order))]


class DamagedSolid(Contributor):
    """Every solid (sub)element through the damage-aware kernel, updating the ply damage:
    unrefined cells whole, refined cells by subelement; with the model's finite kinematics
    each in its co-rotated frame (``subelement.add_damaged_subelement_forces``).

    ``damage``: the ply damage state (its elements and parameters); ``rule_table``: the packed
    rules; ``nodes``: the node arrays; ``elements()``: the structure's solid elements now
    (``Structure.elements``), taken again after each refinement."""

    name = "ply"
    kind = ForceKind.INTERNAL

    def __init__(
        self,
        damage: PlyDamageState,
        rule_table: RuleTable,
        nodes: NodeArrays,
        elements: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]],
        model: LayeredModel | None = None,
    ):
        self.damage = damage
        self.model = model  # its kinematics, read per call (None: small strain)
        self.rule_table = rule_table
        self.nodes = nodes
        self.elements = elements
        self._energy = self._interior_energy = 0.0
        # False while the structure probes a state (``Structure.probing``)
        self.update_damage = True
        self.refined()

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add the elements' forces (N) into the local base and extra DOFs, updating the ply
        damage."""
        self._energy = self._add(f_base, f_extra, "all")

    def add_interior_force(
        self, t: float, f_base: np.ndarray, f_extra: np.ndarray, progress: Callable[[], None]
    ) -> None:
        """``add_force`` of the interior elements only (``NodeArrays.interior``), in chunks
        of ``assembly.INTERIOR_CHUNK`` with a ``progress()`` after each."""
        if self._generation != self.nodes.generation:  # the ready nodes changed
            self.refined()
        energy = 0.0
        for chunk in range(self.damage.interior_chunks):
            energy += self._add(f_base, f_extra, chunk)
            progress()
        self._interior_energy = energy

    def add_boundary_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """``add_force`` of the elements ``add_interior_force`` left."""
        self._energy = self._interior_energy + self._add(f_base, f_extra, "boundary")

    def _add(self, f_base: np.ndarray, f_extra: np.ndarray, part: str | int) -> float:
        return self.damage.add_forces(
            self.rule_table.packed,
            *self.nodes.kernel_arguments(f_base, f_extra),
            update=self.update_damage,
            part=part,
            corotational=self.model is not None and self.model.finite,
        )

    def energy(self) -> float:
        """Secant strain energy (mJ) of this rank's elements at the last ``add_force``."""
        return self._energy

    def state(self) -> dict[str, np.ndarray]:
        return self.damage.state()

    def layout(self, structure) -> dict[str, Rows]:
        """The damage's rows are the owned cells (``parallel.redistribute``)."""
        return {"damage": Rows(structure.cell_keys())}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.damage.restore(state)

    def suspect(self) -> str:
        return "a damaged material?"

    def refined(self) -> None:
        """The kernel computes the structure's elements of now."""
        nodes, cells, plies = self.elements()
        self._generation = self.nodes.generation
        self.damage.set_elements(nodes, cells, plies, self.rule_table, self.nodes.interior(nodes))


class CohesiveElements(Contributor):
    """The cohesive elements (numba, paper Eq. (3) -f^coh), updating their damage; their state
    is the damage and history rows (``CohesiveSet.state``), which persist through refinements.

    ``cells``: the refined cells' sets (the cohesive set is read per call: a refinement makes a
    new one); ``nodes``: the node arrays; ``comm``: for ``suspect``."""

    name = "cohesive"
    kind = ForceKind.INTERNAL

    def __init__(self, cells: RefinedCells, nodes: NodeArrays, comm: MPI.Comm):
        self.cells = cells
        self.nodes = nodes
        self.comm = comm
        self._energy = 0.0

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Subtract the cohesive forces (N) from the local base and extra DOFs."""
        if not len(self.cells.cohesive):  # (an ESL model before it refines: a call saved)
            self._energy = 0.0
            return
        self._energy = self.cells.add_cohesive_forces(*self.nodes.kernel_arguments(f_base, f_extra))

    def energy(self) -> float:
        """Recoverable cohesive energy (mJ) of this rank's elements at the last ``add_force``."""
        return self._energy

    def state(self) -> dict[str, np.ndarray]:
        return self.cells.cohesive.state()

    def layout(self, structure) -> dict[str, Rows]:
        """The rows are the damage rows, each of one (cell, interface)."""
        rows = Rows(structure.cohesive_row_keys())
        return dict.fromkeys(("damage", "history", "insert"), rows)

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.cells.cohesive.restore(state)

    def suspect(self) -> str:
        if self.comm.allreduce(len(self.cells.cohesive), op=MPI.SUM):
            return "a cohesive penalty too stiff for it?"
        return ""


class InternalForces:
    """The structure's internal-force contributors: ``solids`` (the form and the subelements,
    or the damaged solid), then ``cohesive``; ``contributors`` is that list, the order of
    summation."""

    def __init__(self, solids: list[Contributor], cohesive: CohesiveElements, comm: MPI.Comm):
        self.solids = solids
        self.cohesive = cohesive
        self.contributors: list[Contributor] = [*solids, cohesive]
        self.comm = comm

    @classmethod
    def of(
        cls,
        model: LayeredModel,
        refinement: RefinementState,
        cells: RefinedCells,
        nodes: NodeArrays,
        damage: PlyDamageState | None,
        elements: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]],
    ) -> InternalForces:
        """The contributors of a structure: every solid element through the damaged kernel with
        ply ``damage``, else (None) through the elastic one; the cohesive elements in both."""
        if damage is not None:
            solids = [DamagedSolid(damage, cells.rule_table, nodes, elements, model)]
        else:
            solids = [ElasticSolid(model, refinement, cells.rule_table, nodes, elements)]
        return cls(solids, CohesiveElements(cells, nodes, model.comm), model.comm)

    def local_energies(self) -> np.ndarray:
        """(2,) mJ, this rank's share of ``energies`` (local: no communication)."""
        return np.array([sum(c.energy() for c in self.solids), self.cohesive.energy()])

    def energies(self) -> tuple[float, float]:
        """Collective: (strain energy of the solids, recoverable cohesive energy) in mJ at the
        state of their last ``add_force``, summed over ranks."""
        solid, cohesive = summed(self.comm, self.local_energies())
        return float(solid), float(cohesive)
