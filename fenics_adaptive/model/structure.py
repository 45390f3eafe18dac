"""What the explicit solver integrates: base nodes (a DOLFINx space) and extra nodes, their lumped
masses, prescribed DOFs and internal forces, for the three kinds of model.

Units: N, mm, s, tonne.

- ESL: one cell through the thickness.
- layerwise (LW) reference: one cell layer per sublaminate, and cohesive elements
  joining the node sets of split layer boundaries (the high-fidelity model).
- adaptive: the ESL mesh whose cells are refined through the thickness (weak: extra nodes,
  strong: duplicated extra nodes + a cohesive element). Refined cells are computed subelement
  by subelement (paper Eqs. (3)-(7)):

      f_int = f(unrefined cells) + sum_i P_i^T f^sublam_i - sum_j P_j^T f^coh_j

The solid terms are one force contributor (``model.internal_forces``: every solid element
through one numba kernel, elastic or, with ply damage, damaged; the base model's UFL form keeps
the unrefined cells for static solves), the cohesive elements another; with the tie forces of
new strong interfaces they are the structure's ``contributors`` (``model.forces``), which the
solver sums with a run's own. ``internal_force()`` sums the internal ones into the blocks.

Refinement (``Structure.refine``) is collective and happens between steps: new extra nodes get
positions and velocities interpolated from the cell's active nodes below and above (weak) or
copied from set A (strong); the refined cells' old (sub)element masses are taken off their
nodes and the new subelements' masses put on (total mass unchanged); the maps, the
contributors' cells (``Contributor.refined``), constraints, face loads
(``ResolvedLoads.refine``: onto the subelement faces, extra nodes included) and stable time step
are rebuilt. Extra nodes on the border of a refined region follow their unrefined neighbour
(``border``). The per-step path allocates nothing.

The structure composes parts with one job each: ``element.rules.RuleTable`` (the packed rules of
every ply span), ``adaptivity.refinement.RefinementState`` (interface states, the refinement
log and energy), ``adaptivity.stabilisation.StabilisationState`` (damping windows, tie forces),
``model.ply_damage_state.PlyDamageState`` (matrix damage per cell and ply),
``model.refined_cells.RefinedCells`` (subelements and cohesive elements),
``model.internal_forces.InternalForces`` (the internal-force contributors and their stored
energies), ``model.blocks.LumpedBlocks`` (the solver's two blocks: lumped masses, force vectors,
border constraints, prescribed DOFs); ``state()`` / ``restore()`` gather their
history-dependent arrays for a checkpoint. The stable step is computed in
``model.stable_step``, what one reads off a structure for reports in ``model.diagnostics``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator

import numpy as np
from dolfinx import fem

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.adaptivity.equilibration import BeforeRefinement, Equilibrated, equilibrate
from fenics_adaptive.adaptivity.refinement import RefinementState
from fenics_adaptive.adaptivity.stabilisation import (
    DampingWindow,
    StabilisationState,
    TieRelease,
    Ties,
)
from fenics_adaptive.element.geometry import thickness_weight
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.element.solid_shell import enhanced_displacement
from fenics_adaptive.errors import InputError
from fenics_adaptive.model.assembly import CohesiveSet
from fenics_adaptive.model.blocks import Block, LumpedBlocks, subelement_mass_change
from fenics_adaptive.model.border import border_constraints, column_counts
from fenics_adaptive.model.forces import ForceContributor, hooks
from fenics_adaptive.model.forms import LayeredModel
from fenics_adaptive.model.internal_forces import InternalForces, NodeArrays
from fenics_adaptive.model.loading import (
    Amplitude,
    PrescribedMotion,
    ResolvedLoads,
    extra_node_prescriptions,
)
from fenics_adaptive.model.mass_scaling import SelectiveMass, adaptive_refused
from fenics_adaptive.model.ply_damage_state import PlyDamageState
from fenics_adaptive.model.refined_cells import RefinedCells
from fenics_adaptive.model.stable_step import (
    cohesive_time_step,
    nodal_interface_areas,
    stable_time_step,
)
from fenics_adaptive.model.tie_forces import TieForces
from fenics_adaptive.model.topology import CellColumnTable
from fenics_adaptive.parallel.redistribute import (
    PARTIAL,
    REPLICATED,
    Layout,
    NotMovable,
    Rows,
    contributor_layouts,
    dof_keys,
    extra_node_keys,
    node_keys,
)
from fenics_adaptive.parallel.reductions import summed
from fenics_adaptive.parallel.threads import one_thread_per_rank
from fenics_adaptive.settings.adaptivity import Interfaces, Stabilisation
from fenics_adaptive.settings.kinds import InterfaceState


def _forwarded(path: str, doc: str) -> property:
    """A read-only attribute of ``Structure`` held by one of its parts (``path``: "part.name").
    A plain function as the getter, so that the API pages link it to this module's source."""
    part, name = path.split(".")

    def get(structure: Structure):
        return getattr(getattr(structure, part), name)

    get.__doc__ = doc
    return property(get, doc=doc)


def _part(state: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)}


class Structure:
    """Base model + (optional) enrichment + cohesive elements, as the solver sees them."""

    def __init__(
        self,
        base: LayeredModel,
        loads: ResolvedLoads,
        cohesive: CohesiveSet | None = None,
        interfaces: Interfaces | None = None,
        law_params: np.ndarray | None = None,
        stabilisation: Stabilisation | None = None,
        failures: dict | None = None,
        ply_damage: bool = False,
        erosion: bool = False,
        erosion_volume_ratio: float = 0.2,
    ):
        self.base = base
        self.failures = failures or {}
        self.ply_damage = ply_damage
        if erosion and not ply_damage:
            raise ValueError("erosion needs ply damage")
        self.erosion = erosion
        self.erosion_volume_ratio = erosion_volume_ratio
        self.stabilisation = stabilisation or Stabilisation()
        self.loads = loads
        self.comm = base.comm
        # the ranks are the parallelism: BLAS pools of several ranks on shared cores spin
        # against each other (a history row 15 ms instead of 1 on two ranks)
        one_thread_per_rank(self.comm)
        self.stabilisation_state = StabilisationState(
            self.stabilisation, self.comm, TieRelease.of_law(law_params)
        )
        V = base.V
        self.n_base = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
        self.X_base = V.tabulate_dof_coordinates()[: self.n_base].copy()
        self.v_base = fem.Function(V, name="velocity").x
        self.interfaces = interfaces or Interfaces()
        self.motions = _motions(loads, self.interfaces, len(base.layer_laminates))

        if len(base.layer_laminates) > 1 and (
            self.interfaces.refine or self.interfaces.initial != "none"
        ):
            raise ValueError("only an ESL mesh (one cell through the thickness) can refine")
        # the whole laminate (an LW model spreads it over its mesh layers) and the plies of each
        # owned cell
        laminate = base.laminate
        self.laminate = laminate
        n_interfaces = laminate.n_plies - 1
        self.cell_plies = _cell_plies(base)
        self.refinement = RefinementState(base.n_owned_cells, n_interfaces, self.interfaces)
        self.columns = CellColumnTable(base)
        # the columns' arrays as the structure's own (read by indicators, contact, output)
        self.bottom_local, self.top_local = self.columns.bottom_local, self.columns.top_local
        # (n_owned_cells, 8) each cell's base nodes, bottom face then top (local numbers)
        self.cell_nodes = np.hstack([self.bottom_local, self.top_local])
        self.bottom_global = self.columns.bottom_global
        self.original_cell = self.columns.original_cell
        # each local base node's number in the mesh as generated: the same on any partition
        self.node_keys = node_keys(base)
        self.extra = enr.ExtraNodes(self.comm, max(n_interfaces, 1), V.dofmap.index_map)
        # the ply-damage kernel integrates ply by ply: no pre-integrated rule for it
        self.rule_table = RuleTable(
            laminate,
            base.points_per_ply,
            base.shear_correction,
            base.enhanced_strain,
            base.preintegrate and not ply_damage,
        )
        self.refined_cells = RefinedCells(
            self.rule_table,
            cohesive if cohesive is not None else CohesiveSet.empty(np.zeros(8)),
            law_params,
        )
        self.ply_damage_state: PlyDamageState | None = None
        if ply_damage:
            self._setup_ply_damage()
        self.node_arrays = NodeArrays.of(self.X_base, base.u.x, self.extra)
        # no extra nodes yet, no border
        self._mark_ready(np.zeros(0, dtype=np.int64))
        self.internal_forces = InternalForces.of(
            base,
            self.refinement,
            self.refined_cells,
            self.node_arrays,
            self.ply_damage_state,
            self.elements,
        )
        # the structure's force contributors (model.forces): internal forces, then tie forces
        self.contributors: list[ForceContributor] = [
            *self.internal_forces.contributors,
            TieForces(self.stabilisation_state, lambda: self.extra.vectors["u"].array),
        ]
        # the selectively scaled mass of the base nodes, if a run asks for it (set by the
        # solver: ``model.mass_scaling.selective_mass``); None: the lumped masses alone
        self.scaled_mass: SelectiveMass | None = None
        # what the last refinement's equilibration did (``adaptivity.equilibration``), None:
        # nothing
        self.last_equilibrated: Equilibrated | None = None
        # the base and extra blocks' accelerations (owned DOFs, mm/s^2) of the state being
        # refined, from the solver that runs the structure (``ExplicitSolver`` sets it); None:
        # at rest
        self.accelerations: Callable[[], tuple[np.ndarray, np.ndarray] | None] = lambda: None
        # the contact contributors' forces per block (owned DOFs, N) at that state, None
        # without contact (set by the solver): the equilibration holds the base nodes they press
        self.contact_forces: Callable[[], list[np.ndarray] | None] = lambda: None
        # (node arrays' generation, cohesive pairs' stable step and where): ``cohesive_step``
        self._cohesive_step: tuple[int, tuple[float, str]] | None = None
        # (node arrays' generation, the lower nodes' interface areas): ``interface_areas``
        self._interface_areas: tuple[int, tuple[np.ndarray, np.ndarray]] | None = None
        self.lumped = LumpedBlocks(
            V, base.mass, self.extra.index_map, loads.fixed, loads.fixed_motion
        )
        self._rebuild_blocks()

    # ------------------------------------------------------------------ what the solver uses
    @property
    def blocks(self) -> list[Block]:
        """[base block, extra block] (``model.blocks.LumpedBlocks``)."""
        return self.lumped.blocks

    base_block = _forwarded("lumped.base_block", doc="The base nodes' block.")
    halo = _forwarded(
        "lumped.halo",
        doc="The halo exchange of both blocks (``parallel.Halo``; rebuilt when the extra "
        "nodes change).",
    )
    extra_block = _forwarded("lumped.extra_block", doc="The extra nodes' block.")
    subelements = _forwarded(
        "refined_cells.subelements",
        doc="The refined cells' subelements (``RefinedCells.subelements``).",
    )
    subelement_cells = _forwarded("refined_cells.cells", doc="(n,) owned cell of each subelement.")
    subelement_plies = _forwarded(
        "refined_cells.plies",
        doc="(n, 2) laminate plies [first, stop) of each subelement.",
    )
    subelement_speeds = _forwarded(
        "refined_cells.speeds",
        doc="(n,) dilatational wave speed (mm/s) of each subelement.",
    )
    cohesive = _forwarded(
        "refined_cells.cohesive",
        doc="The cohesive elements (an LW model's, or those of the strong interfaces).",
    )
    f_base = _forwarded("lumped.f_base", doc="Internal force (N) of the base DOFs.")
    f_extra = _forwarded("lumped.f_extra", doc="Internal force (N) of the extra DOFs.")
    mass_base = _forwarded(
        "lumped.mass_base",
        doc="Assembled lumped mass (tonne) of the base DOFs (before the border's transfer).",
    )
    mass_extra = _forwarded(
        "lumped.mass_extra",
        doc="Assembled lumped mass (tonne) of the extra DOFs (before the border's transfer).",
    )
    border = _forwarded(
        "lumped.border",
        doc="The extra DOFs on the border of refined regions, bound to their masters.",
    )

    def internal_force(self, t: float = 0.0) -> None:
        """Collective: f_int at time t (s) of the structure's internal-force contributors
        (``internal_forces``) into both blocks' ``f`` (owned entries complete)."""
        self.lumped.add_internal_forces(t, self.internal_forces.contributors)

    @contextlib.contextmanager
    def probing(self) -> Iterator[None]:
        """Inside the block ``internal_force`` probes: it changes no damage. The ply damage
        is not updated (its contributor's switch), the other internal-force contributors'
        states (the cohesive damage) are put back as they were when the block ends."""
        contributors = self.internal_forces.contributors
        frozen = [c for c in contributors if getattr(c, "update_damage", False)]
        saved = [
            (c, {k: np.copy(v) for k, v in c.state().items()})
            for c in contributors
            if c not in frozen
        ]
        for contributor in frozen:
            contributor.update_damage = False
        try:
            yield
        finally:
            for contributor in frozen:
                contributor.update_damage = True
            for contributor, state in saved:
                if state:
                    contributor.restore(state)

    def follow_border(self, velocity: bool = False) -> None:
        """Put the constrained extra DOFs (owned and ghosts) where their masters are (after
        the masters moved and were forward-scattered); also their velocities if asked."""
        if not len(self.lumped.border):  # (each .array of a DOLFINx vector costs 2 us)
            return
        self.lumped.follow_border(
            self.base.u.x.array, self.extra.vectors["u"].array, displacement=True
        )
        if velocity:
            self.lumped.follow_border(self.v_base.array, self.extra.vectors["v"].array)

    def cell_vertices(self) -> np.ndarray:
        """Reference vertex coordinates (n_cells, 8, 3) mm of the owned cells."""
        return self.X_base[self.base.V.dofmap.list[: self.base.n_owned_cells]]

    def _mechanical_energy(self, evaluated: bool = False) -> tuple[float, float]:
        """(kinetic, solid strain + recoverable cohesive) energy (mJ) of the current state, at
        the damage as it is (``evaluated``: the internal forces already are, so probed). A
        refinement changes the strains of the cells it refines a little (their subelements
        condense their own enhanced thickness strain): damage that grows from that belongs to
        the next step, whose damage law books its dissipation, not to the refinement's energy
        change."""
        if not evaluated:
            with self.probing():
                self.internal_force()
        return self.kinetic_energy(), sum(self.internal_forces.energies())

    def kinetic_energy(self) -> float:
        """Collective: kinetic energy (mJ) of both blocks."""
        return self.lumped.kinetic_energy()

    def total_mass(self) -> float:
        """Collective: the mass (tonne) the solver integrates."""
        return self.lumped.total_mass()

    def momentum(self) -> np.ndarray:
        """Collective: linear momentum (3,) tonne mm/s."""
        return self.lumped.momentum()

    def cohesive_step(self) -> tuple[float, str]:
        """Collective: ``stable_step.cohesive_time_step`` of the structure as it is refined now,
        computed once per refinement (the node arrays' generation)."""
        generation = self.node_arrays.generation
        if self._cohesive_step is None or self._cohesive_step[0] != generation:
            self._cohesive_step = (generation, cohesive_time_step(self))
        return self._cohesive_step[1]

    def interface_areas(self) -> tuple[np.ndarray, np.ndarray]:
        """Collective: ``stable_step.nodal_interface_areas`` of the structure as it is refined
        now (base nodes, extra nodes; mm^2), computed once per refinement (the node arrays'
        generation) for the cohesive step and the ties alike."""
        generation = self.node_arrays.generation
        if self._interface_areas is None or self._interface_areas[0] != generation:
            self._interface_areas = (generation, nodal_interface_areas(self))
        return self._interface_areas[1]

    def stable_time_step(self, current: bool = False) -> tuple[float, str]:
        """Collective: (the stable step (s) of the central-difference scheme, where it is
        attained), reduced over ranks (``model.stable_step.stable_time_step``; ``current``: of
        the deformed cells). The caller applies the safety factor."""
        return stable_time_step(self, current)

    def _setup_ply_damage(self) -> None:
        """Ply damage per (cell, ply): every cell leaves the UFL form for the damage-aware
        numba kernel (``internal_forces.DamagedSolid``, the same for ESL, adaptive and LW
        cells)."""
        self.ply_damage_state = PlyDamageState(
            self.laminate,
            self.failures,
            self.rule_table,
            self.cell_vertices(),
            self.cell_plies,
            self.comm,
            self.base.element_frames(np.arange(self.base.n_owned_cells)),
            erode=self.erosion,
            min_volume_ratio=self.erosion_volume_ratio,
        )
        self.base.set_ufl_cells([np.zeros(0, np.int32)] * len(self.base.layer_laminates))

    damage_state = _forwarded(
        "ply_damage_state.damage",
        doc="(n_cells, n_plies, N_STATE) ply damage state of the owned cells (with ply damage).",
    )

    def scale_matrix_strength(self, cells: np.ndarray, plies: Iterable[int], factor: float) -> None:
        """Let the matrix of these plies (0-based) in these owned cells crack at ``factor`` times
        the transverse strength: below 1 a flaw that decides where the first crack forms where
        the stress is uniform (between the loading points of a four-point bending test), above
        1 cells kept from crushing under a roller. Sets the ply's crack-onset energy to
        (factor YT)^2 / (2 C22)."""
        if not self.ply_damage:
            raise InputError("matrix_strength", "needs model.ply_damage = true")
        self.ply_damage_state.scale_matrix_strength(cells, plies, factor)

    def element_rules(self, plies: np.ndarray) -> np.ndarray:
        """Index into ``subelements.rules`` of the packed rule of each (sub)element spanning
        laminate plies ``plies`` (n, 2) [first, stop), as ``elements`` gives them."""
        return self.rule_table.rule_of(plies)

    def elements(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every solid element of this rank: nodes (n, 8) in combined local indices, the owned
        cell each belongs to, and its plies [first, stop) of the laminate: unrefined cells
        (whole cells: all plies, or an LW layer's) and the subelements of refined ones."""
        unrefined = self.refinement.unrefined_cells()
        nodes = self.cell_nodes[unrefined]
        cells = unrefined.astype(np.int64)
        return self.refined_cells.elements(nodes, cells, self.cell_plies[unrefined])

    # ------------------------------------------------------------------ checkpoint
    def state(self) -> dict[str, np.ndarray]:
        """The history-dependent arrays of this rank, each part's under its prefix:
        ``refinement_*`` (the log of refinements and their energy), ``<name>_*`` of each
        contributor (``cohesive_*``: the cohesive damage, ``ply_*``: the ply damage),
        ``tie_*``, ``window_*`` (stabilisation), ``border_offsets`` (``record_offsets``)."""
        parts = [("refinement_", self.refinement)]
        parts += [(f"{c.name}_", c) for c in self.contributors]
        parts.append(("", self.stabilisation_state))
        state = {prefix + k: v for prefix, part in parts for k, v in part.state().items()}
        state["border_offsets"] = self.lumped.offsets.copy()
        return state

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Collective: replay the logged refinements of ``state`` (as ``state`` gives it) on a
        structure built without its initial refinement, then put the stored arrays back."""
        self.replay(state)
        self.put_back(state)

    def replay(self, state: dict[str, np.ndarray]) -> None:
        """Collective: replay the logged refinements of ``state`` (``refinement_*``: times,
        counts and requests of this rank's cells) on a structure built without its initial
        refinement, and put back the refinement energy."""

        def replay(requests: list[tuple[int, int, int]], t: float) -> None:
            self.refine(requests, t, balance=False)
            self.stabilisation_state.discard_requests()

        self.refinement.restore(_part(state, "refinement_"), replay)

    def put_back(self, state: dict[str, np.ndarray]) -> None:
        """The stored arrays of ``state`` (as ``state`` gives them) put back on a structure
        at the refinement they were taken at (``replay``)."""
        for contributor in self.contributors:
            own = _part(state, f"{contributor.name}_")
            if own:
                contributor.restore(own)
        self.stabilisation_state.restore(state)
        if "border_offsets" in state:  # (a checkpoint of an earlier version: none, as then)
            self.lumped.offsets[:] = state["border_offsets"]

    def layout(self) -> dict[str, Layout]:
        """How the rows of ``state()``'s arrays are indexed, by the same names
        (``parallel.redistribute``; the refinement log's requests: ``request_cells``). Raises
        ``NotMovable`` while a refinement's ties or damping windows act, or for a contributor
        with a state and no layout."""
        stabilisation = self.stabilisation_state
        if stabilisation.ties or stabilisation.damping_windows:
            raise NotMovable("a refinement's ties or damping windows still act")
        out: dict[str, Layout] = {
            "refinement_times": REPLICATED,
            "refinement_energy": REPLICATED,
            "tie_work": PARTIAL,
        }
        out.update(contributor_layouts(self.contributors, self))
        dofs = self.lumped.border.dofs - 3 * self.n_base
        extra_dofs = dof_keys(self.extra_node_keys())
        out["border_offsets"] = Rows(extra_dofs[dofs], dofs // 3 < self.extra.n_owned)
        return out

    def extra_node_keys(self) -> np.ndarray:
        """(owned + ghost extra nodes,) their stable keys (``redistribute.extra_node_keys``)."""
        return extra_node_keys(self)

    def cell_keys(self) -> np.ndarray:
        """(owned cells,) their original numbers (the same on any partition)."""
        return self.original_cell

    def cohesive_row_keys(self) -> np.ndarray:
        """(cohesive damage rows,) int64 stable keys: the original number of the row's cell
        times the interfaces, plus the interface - 1; an adaptive row's cell is the refined
        cell, a layerwise row's its lower cell (whose top face is the element's lower face)."""
        n_interfaces = max(self.laminate.n_plies - 1, 1)
        cohesive = self.cohesive
        keys = np.full(len(cohesive.damage), -1, dtype=np.int64)
        for (cell, interface), row in self.refinement.damage_rows.items():
            keys[row] = self.original_cell[cell] * n_interfaces + interface - 1
        if len(self.refinement.damage_rows) == 0 and len(cohesive.nodes):
            by_top_face = {tuple(face): c for c, face in enumerate(self.top_local.tolist())}
            lower = [by_top_face[tuple(face)] for face in cohesive.nodes[:, :4].tolist()]
            keys[cohesive.damage_row] = (
                self.original_cell[lower] * n_interfaces + cohesive.interface - 1
            )
        return keys

    def request_cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(original number (n,), in-plane centroid (n, 2) mm) of the cell of each logged
        refinement request (the rows of ``state()["refinement_requests"]``)."""
        cells = self.refinement.state()["requests"][:, 0].astype(np.int64)
        vertices = self.X_base[self.base.V.dofmap.list[cells]]  # (those cells' only)
        return self.original_cell[cells], vertices.mean(axis=1)[:, :2]

    # ------------------------------------------------------------------ stabilisation
    @property
    def ties(self) -> list[Ties]:
        """The active tie forces (``StabilisationState.ties``)."""
        return self.stabilisation_state.ties

    @ties.setter
    def ties(self, ties: list[Ties]) -> None:
        self.stabilisation_state.ties = ties

    def start_stabilisation(self, t: float) -> None:
        """Collective, right after a refinement at time t (s): open the damping window of the
        newly weakly refined cells' nodes and set the tie forces of the new strong node pairs from
        the refined structure's internal forces and face loads at t."""
        self.stabilisation_state.start(
            t, self._nodes_of_cells, lambda: self._extra_force_and_mass(t)
        )

    def _extra_force_and_mass(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Collective: the extra nodes' net internal force f_int - f_load (n, 3) N (the face
        loads at time t (s) on them taken off: a node pair on a loaded face moves together
        under both), lumped mass (n,) tonne (after the border's transfer) and interface area
        (n,) mm^2 (``interface_areas``), owned nodes, at the current state."""
        self.internal_force()  # collective (reverse scatters): on every rank
        mass = self.extra_block.mass.reshape(-1, 3)[:, 0]
        n_owned = 3 * len(mass)
        force = self.f_extra.array[:n_owned].reshape(-1, 3)
        _, area = self.interface_areas()
        return force - self.loads.extra_force(t, n_owned), mass, area[: len(mass)]

    def discard_stabilisation_requests(self) -> None:
        """Forget what the last refinement would stabilise (a restart replaying refinements
        restores the stabilisation state it stored instead)."""
        self.stabilisation_state.discard_requests()

    def active_damping(self, t: float) -> list[DampingWindow]:
        """The damping windows open at time t (s)."""
        return self.stabilisation_state.active_damping(t)

    def _nodes_of_cells(self, cells: np.ndarray) -> list[np.ndarray]:
        """Collective: owned DOFs (base block, extra block) of the nodes of these owned cells
        and of their subelements (``LumpedBlocks.owned_dofs``)."""
        nodes, owner_cells, _ = self.elements()
        return self.lumped.owned_dofs(nodes[np.isin(owner_cells, cells)].ravel())

    # ------------------------------------------------------------------ refinement
    interface_state = _forwarded(
        "refinement.interface_state",
        doc="(n_cells, n_interfaces) NONE, WEAK or STRONG of each owned cell's interfaces.",
    )
    weak_since = _forwarded(
        "refinement.weak_since",
        doc="(n_cells, n_interfaces) time (s) each interface became weak, inf if not yet.",
    )
    strong_since = _forwarded(
        "refinement.strong_since",
        doc="(n_cells, n_interfaces) time (s) each interface became strong, inf if not yet.",
    )
    damage_rows = _forwarded(
        "refinement.damage_rows",
        doc="Cohesive damage row of each strong (owned cell, interface).",
    )
    refinement_energy = _forwarded(
        "refinement.energy",
        doc="Mechanical energy (mJ) that refinements added in total.",
    )
    last_refinement_potential = _forwarded(
        "refinement.last_potential",
        doc="Potential-energy part (mJ) of the last refinement's change.",
    )

    def refine(
        self, requests: Iterable[tuple[int, int, int]], t: float = 0.0, balance: bool = True
    ) -> bool:
        """Collective: refine owned cells at time t. ``requests``: (local cell, interface, WEAK
        or STRONG); a strong request on an unrefined interface makes it weak first. The nodes
        of the refined cells (base nodes included) and the DOFs it frees are put in balance
        (``adaptivity.equilibration``) if the stabilisation settings ask for it and
        ``balance`` (False: a restart's replay, whose stored state is put back; the initial
        refinement, before there is any motion to balance); ``last_equilibrated`` says what
        that did. Returns whether anything changed on any rank. Raises InputError for
        interfaces not allowed to refine."""
        requests = list(requests)
        target = self.refinement.plan(requests, self.comm)
        old_state = self.interface_state.copy()
        changed = np.flatnonzero((target != old_state).any(axis=1))
        if not summed(self.comm, [len(changed)])[0]:  # (every evaluation: one MPI call)
            return False
        if self.scaled_mass is not None:
            raise adaptive_refused()
        self.refinement.record(t, requests)
        balances = balance and self.stabilisation.equilibrates(self.ply_damage)
        self.stabilisation_state.request(
            changed[
                (
                    (old_state[changed] == InterfaceState.NONE)
                    & (target[changed] >= InterfaceState.WEAK)
                ).any(axis=1)
            ]
        )
        for vector in (
            self.base.u.x,
            self.v_base,
            self.extra.vectors["u"],
            self.extra.vectors["v"],
        ):
            vector.scatter_forward()
        kinetic_before, potential_before = self._mechanical_energy()
        # (the forces of that call, which the equilibration keeps on the DOFs that were free)
        before = BeforeRefinement.of(self, t) if balances else None

        # weak, bottom to top, then strong; an interface no rank changes is skipped by all
        # (each activation is collective). Each interface's cells read only its own column of
        # the states, so they can be taken before the lower interfaces change theirs.
        for selected, activate in (
            (self.refinement.to_weaken, self._activate_weak),
            (self.refinement.to_strengthen, self._activate_strong),
        ):
            interfaces = range(1, self.refinement.n_interfaces + 1)
            cells = [selected(changed, target, interface) for interface in interfaces]
            anywhere = np.zeros(len(cells), dtype=np.int64)
            self.comm.Allreduce(np.array([len(c) for c in cells], dtype=np.int64), anywhere)
            for interface, these, count in zip(interfaces, cells, anywhere, strict=True):
                if count:
                    activate(these, interface, t)

        self.lumped.resize_extra(self.extra.index_map)
        self.lumped.add_mass_change(
            subelement_mass_change(
                changed,
                old_state[changed],
                self.interface_state[changed],
                self._subelement_nodes_many,
                lambda nodes: self.gather(nodes, "X"),
                self.rule_table,
                self.n_base + self.extra.n_local,
            )
        )
        self._rebuild_maps()
        self.node_arrays.refresh(self.extra)
        free_b = self.border.free_b
        self._rebuild_blocks()  # (the new border: which nodes are ready, for the contributors)
        for refined in hooks(self.contributors, "refined"):
            refined()
        # the face loads onto the subelements' faces, extra nodes included, with the new border
        self.loads.refine(
            self.cell_nodes,
            self.subelements.nodes,
            self.subelement_cells,
            lambda nodes: self.gather(nodes, "X"),
            self.border,
            self.base.V.dofmap.index_map,
            self.extra.index_map,
        )
        self._request_ties(self.border.free_b - free_b)
        self.last_equilibrated = (
            equilibrate(self, before, changed, t, self.accelerations(), self.contact_forces())
            if before is not None
            else None
        )
        # The lumped masses move, which changes the kinetic energy; the subelements' own
        # shear factors and enhanced strains and the equilibration change the strain energy:
        # book both (an equilibration leaves the forces evaluated at the final state)
        kinetic, potential = self._mechanical_energy(evaluated=self.last_equilibrated is not None)
        self.refinement.book(kinetic - kinetic_before, potential - potential_before)
        return True

    def _request_ties(self, opened: set) -> None:
        """Ask the stabilisation to tie the strong node pairs that open now: the owned set-B
        nodes (keys ``opened``) no longer bound to their set-A partners."""
        n_interfaces = self.interface_state.shape[1]
        for key in sorted(opened):
            local = self.extra.index[key]
            if local < self.extra.n_owned:
                g, i, _ = enr.key_parts(key, n_interfaces)
                partner = self.extra.index[enr.extra_key(g, i, enr.SET_A, n_interfaces)]
                self.stabilisation_state.request_pair(partner, local)

    def _activate_weak(self, cells: np.ndarray, interface: int, t: float) -> None:
        """New set-A nodes at ``interface`` of ``cells``, placed (u, v, X) on the straight line
        through the subelement they split, then the interface made weak."""
        cells = np.asarray(cells, dtype=np.int64)
        states = self.interface_state[cells]
        n_interfaces = states.shape[1]
        # the active interfaces nearest below and above (0 and n_plies: the cell's faces)
        levels = np.arange(1, n_interfaces + 1)
        active = states != InterfaceState.NONE
        below = np.where(active & (levels < interface), levels, 0).max(axis=1, initial=0)
        above = np.where(active & (levels > interface), levels, n_interfaces + 1).min(
            axis=1, initial=n_interfaces + 1
        )
        nodes = self._subelement_nodes_many(states, below, above, cells)
        fractions = self.laminate.ply_fractions
        w = thickness_weight(fractions, interface, below, above)
        gathered = {name: self.gather(nodes, name) for name in ("u", "v", "X")}
        values = {
            name: (1.0 - w[:, None, None]) * field[:, :4] + w[:, None, None] * field[:, 4:]
            for name, field in gathered.items()
        }
        if not self.base.finite:
            # the split element's enhanced thickness strain, integrated to the new nodes: the
            # subelements start with the strain the element had, so the strain energy does not
            # jump. Not in v: on the straight line the lumped masses keep the momentum exactly
            X, u = gathered["X"], gathered["u"]
            frames = self.base.element_frames(cells)
            turned = (
                [np.einsum("eij,eaj->eai", frames, a) for a in (X, u)] if len(frames) else (X, u)
            )
            alpha = self.rule_table.enhanced_parameters(*turned, np.stack([below, above], axis=1))
            values["u"] += enhanced_displacement(X, alpha, w)
        self.refinement.mark_weak(cells, interface, t)
        self.extra.activate(
            *self.columns.node_requests(cells, interface, enr.SET_A, n_interfaces, values)
        )

    def _activate_strong(self, cells: np.ndarray, interface: int, t: float) -> None:
        """New set-B nodes at ``interface`` of ``cells``, where their set-A partners are, then
        the interface made strong with a fresh cohesive damage row per cell."""
        cells = np.asarray(cells, dtype=np.int64)
        n_interfaces = self.interface_state.shape[1]
        keys = enr.extra_keys(self.bottom_global[cells], interface, enr.SET_A, n_interfaces)
        local = self.extra.locate(keys)
        values = {
            name: self.extra.vectors[name].array.reshape(-1, 3)[local] for name in ("u", "v", "X")
        }
        self.refinement.mark_strong(cells, interface, t)
        self.extra.activate(
            *self.columns.node_requests(cells, interface, enr.SET_B, n_interfaces, values)
        )
        self.cohesive.grow_rows(len(self.damage_rows))

    # ------------------------------------------------------------------ maps and bookkeeping
    def _subelement_nodes_many(
        self, states: np.ndarray, first: np.ndarray, stop: np.ndarray, cells: np.ndarray
    ) -> np.ndarray:
        """(m, 8) nodes of subelements plies first:stop of ``cells`` in states ``states``."""
        return self.columns.subelement_nodes(states, first, stop, cells, self.extra.locate)

    def _rebuild_maps(self) -> None:
        """The subelements and cohesive elements of the refined cells (``RefinedCells``)."""
        refined = self.refinement.refined_cells()
        n_interfaces = self.refinement.n_interfaces
        self.refined_cells.rebuild(
            refined,
            self.interface_state[refined],
            self.damage_rows,
            self._subelement_nodes_many,
            lambda interfaces, cells: self.columns.cohesive_nodes(
                interfaces, cells, n_interfaces, self.extra.locate
            ),
        )

    def _rebuild_blocks(self) -> None:
        """Collective: border constraints and prescribed extra DOFs of the current extra nodes,
        handed to the blocks (``LumpedBlocks.rebuild``)."""
        prescribed = extra_node_prescriptions(
            self.motions, self.base, self.extra, self.columns.top_of, self.refinement.n_interfaces
        )
        self.extra_prescribed = prescribed
        border = self.border
        if self.extra.index_map.size_global:  # the same on every rank: column_counts is collective
            counts = column_counts(
                self.comm, self.base.V.dofmap.index_map, self.bottom_local, self.interface_state
            )
            border = border_constraints(
                counts,
                self.extra,
                self.columns.top_of,
                self.laminate.ply_fractions,
                self.n_base,
                prescribed >= 0,
            )
        self.lumped.rebuild(
            border,
            prescribed,
            (self.base.u.x, self.v_base),
            (self.extra.vectors["u"], self.extra.vectors["v"]),
        )
        self._mark_ready(border.dofs // 3)  # (3 combined node index + component)

    def _mark_ready(self, constrained: np.ndarray) -> None:
        """Which nodes' displacements a step knows before the halo exchange: the owned nodes
        but the ``constrained`` ones (combined local indices), on several ranks."""
        self.node_arrays.mark_ready(
            self.base.V.dofmap.index_map.size_local,
            self.extra.n_owned,
            constrained,
            self.comm.size > 1,
        )

    def gather(self, nodes: np.ndarray, name: str) -> np.ndarray:
        """Values (*nodes.shape, 3) of ``name``: "u" (displacement, mm), "v" (velocity, mm/s)
        or "X" (reference position, mm), at combined local node indices (i < n_base: base node
        i, else extra node i - n_base), e.g. ``subelements.nodes`` or ``cohesive.nodes``."""
        if name == "X":
            base = self.X_base
        else:
            base = (self.base.u.x if name == "u" else self.v_base).array.reshape(-1, 3)
        extra = self.extra.vectors[name].array.reshape(-1, 3)
        is_base = nodes < self.n_base
        out = np.empty((*nodes.shape, 3))
        out[is_base] = base[nodes[is_base]]
        out[~is_base] = extra[nodes[~is_base] - self.n_base]
        return out


def _motions(loads: ResolvedLoads, interfaces: Interfaces, n_layers: int) -> list[PrescribedMotion]:
    """The loads' prescribed motions, then the symmetry interfaces' u_z = 0 (ESL mesh only)."""
    motions = list(loads.motions)
    for i in interfaces.symmetry if n_layers == 1 else ():
        motions.append(
            PrescribedMotion(f"interface{i}", "z", "displacement", 0.0, Amplitude.constant(0))
        )
    return motions


def _cell_plies(base: LayeredModel) -> np.ndarray:
    """(n_cells, 2) plies [first, stop) of the whole laminate each owned cell holds."""
    cell_plies = np.zeros((base.n_owned_cells, 2), dtype=np.int64)
    first = 0
    for k, layer in enumerate(base.layer_laminates):
        cell_plies[base.layer_cells(k)] = (first, first + layer.n_plies)
        first += layer.n_plies
    return cell_plies


def cells_in_x_range(structure: Structure, x_min: float, x_max: float) -> np.ndarray:
    """Owned cells whose centroid lies in x_min <= x <= x_max."""
    x = structure.cell_vertices()[:, :, 0].mean(axis=1)
    return np.flatnonzero((x >= x_min) & (x <= x_max)).astype(np.int32)
