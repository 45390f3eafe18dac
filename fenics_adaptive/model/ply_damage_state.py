"""The damage state of a structure's plies (matrix cracks, broken fibres): per (owned cell,
laminate ply) the state of ``materials.ply_damage``, its crack band widths and reference volume,
and the (sub)elements the damage-aware numba kernel computes.

Units: N, mm, s, tonne (energies mJ).

With ply damage, every cell leaves the UFL form for the damage-aware kernel (the same for ESL,
adaptive and layerwise cells). The state rows are the owned cells; a subelement reads and
updates the rows of its cell's plies, so a refinement keeps the damage of each ply.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from mpi4py import MPI

from fenics_adaptive.element.geometry import slab_vertices, thickness_weight
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.element.subelement import add_damaged_subelement_forces, elements_eroded
from fenics_adaptive.element.timestep import hexahedron_volumes
from fenics_adaptive.materials.laminate import Laminate
from fenics_adaptive.materials.ply_damage import (
    S_DISSIPATED,
    S_ERODED,
    S_FIBRE_DISSIPATED,
    S_Y0,
    check_band_width,
    concatenate_ply_damage,
    crack_band_widths,
    new_state,
    pack_ply_damage,
)
from fenics_adaptive.model.assembly import chunk_bounds
from fenics_adaptive.parallel.reductions import dot


class PlyDamageState:
    """Ply damage of this rank's owned cells.

    ``laminate``: the whole laminate; ``failures``: the ply failure parameters by material
    name; ``rule_table``: the structure's rules (the damage parameters are packed per rule
    span); ``cell_X`` (n_cells, 8, 3) mm: the owned cells' reference vertices; ``cell_plies``
    (n_cells, 2): the plies [first, stop) of each cell. Collective (the band widths are checked
    against the widest over all ranks). Raises InputError where a cell is too wide for a ply's
    crack band. ``frames`` (n_cells, 3, 3): the cells' frames on a curved shell (the kernel
    computes each element in its cell's, ``LayeredModel.element_frames``); (0, 3, 3) or None:
    the global frame. ``erode``: (sub)elements whose plies' fibres have all failed leave the
    force computation (``subelement``: Erosion), and those crushed below
    ``min_volume_ratio`` (``add_damaged_subelement_forces``)."""

    def __init__(
        self,
        laminate: Laminate,
        failures: dict,
        rule_table: RuleTable,
        cell_X: np.ndarray,
        cell_plies: np.ndarray,
        comm: MPI.Comm,
        frames: np.ndarray | None = None,
        erode: bool = False,
        min_volume_ratio: float = 0.0,
    ):
        if rule_table.preintegrate:
            raise ValueError("ply damage needs rules ply by ply (RuleTable(preintegrate=False))")
        plies = laminate.plies
        self.laminate = laminate
        self.failures = failures
        self.comm = comm
        self.erode = bool(erode)
        self.min_volume_ratio = float(min_volume_ratio)
        # the elements erosion has removed on this rank in this process (the kernel adds them:
        # a diagnostic for a debugger, not a state: a restart starts it at 0)
        self.eroded_count = np.zeros(1, dtype=np.int64)
        self.frames = np.zeros((0, 3, 3)) if frames is None else np.asarray(frames)
        if len(self.frames):  # the band widths across the fibres in each cell's frame
            cell_X = np.einsum("cij,caj->cai", self.frames, cell_X)
        self.pack = concatenate_ply_damage(
            [pack_ply_damage(plies[a:b], failures) for a, b in rule_table.spans]
        )
        n_cells = len(cell_X)
        # crack band widths (mm) of each ply of each cell, across and along its fibres
        self.band_width = np.zeros((n_cells, len(plies), 2))
        for k, ply in enumerate(plies):
            in_cell = (cell_plies[:, 0] <= k) & (k < cell_plies[:, 1])
            for cell in np.flatnonzero(in_cell):
                self.band_width[cell, k] = crack_band_widths(cell_X[cell], ply.angle)
            # the widest bands over all ranks: every rank takes the same decision
            local = self.band_width[in_cell, k].max(axis=0) if in_cell.any() else np.full(2, -1.0)
            widest = np.empty(2)
            comm.Allreduce(np.ascontiguousarray(local), widest, op=MPI.MAX)
            if widest[0] >= 0.0:
                check_band_width(ply.material, failures[ply.material.name], *widest)
        self.damage = new_state(n_cells, len(plies))  # (n_cells, n_plies, N_STATE)
        # reference volume (mm^3) of each ply of each cell: the ply's dissipation density
        # (ply_damage S_DISSIPATED) times it is its dissipated energy
        fractions = laminate.ply_fractions
        self.ply_volumes = np.zeros((n_cells, len(plies)))
        for k in range(len(plies)):
            in_cell = np.flatnonzero((cell_plies[:, 0] <= k) & (k < cell_plies[:, 1]))
            lo, hi = cell_plies[in_cell, 0], cell_plies[in_cell, 1]
            # the ply's place in its cell's own thickness (an LW cell holds some plies)
            w_lo = thickness_weight(fractions, k, lo, hi)
            w_hi = thickness_weight(fractions, k + 1, lo, hi)
            ply_X = slab_vertices(cell_X[in_cell, :4], cell_X[in_cell, 4:], w_lo, w_hi)
            self.ply_volumes[in_cell, k] = hexahedron_volumes(ply_X)
        self.elements: tuple[np.ndarray, ...] = ()  # set_elements
        self._spans = np.zeros((0, 2), dtype=np.int64)
        self._parts: dict[str | int, tuple[np.ndarray, ...]] = {}
        self.interior_chunks = 0

    def set_elements(
        self,
        nodes: np.ndarray,
        cells: np.ndarray,
        plies: np.ndarray,
        rule_table: RuleTable,
        interior: np.ndarray | None = None,
    ) -> None:
        """The (sub)elements the kernel computes (``Structure.elements``): nodes (n, 8) combined
        local indices, owned cell of each, its plies [first, stop); ``interior`` (n,) bool:
        those ``add_forces(part="interior")`` computes (None: all), taken first, also as parts
        0 .. ``interior_chunks`` - 1 (``assembly.chunk_bounds``)."""
        first = slice(None) if interior is None else np.argsort(~interior, kind="stable")
        cells = cells.astype(np.int64)[first]
        self._spans = np.asarray(plies[first]).astype(np.int64)  # [first, stop) of each
        self.elements = (
            np.ascontiguousarray(nodes[first]),
            rule_table.rule_of(plies[first]),
            cells,
            np.asarray(plies[first, 0]).astype(np.int64),
            # each element's frame (its cell's), or none: the kernel then rotates nothing
            np.ascontiguousarray(self.frames[cells]) if len(self.frames) else self.frames,
        )
        n = len(nodes) if interior is None else int(np.count_nonzero(interior))
        self._parts = {
            "all": self.elements,
            "interior": self._part(slice(None, n)),
            "boundary": self._part(slice(n, None)),
        }
        bounds = chunk_bounds(n)  # the interior in chunks: parts 0, 1, ...
        self.interior_chunks = len(bounds)
        for k, (start, stop) in enumerate(bounds):
            self._parts[k] = self._part(slice(start, stop))

    def _part(self, part: slice) -> tuple[np.ndarray, ...]:
        """The element arrays of ``part`` of the elements (the frames: none stay none)."""
        *arrays, frames = self.elements
        return (*(a[part] for a in arrays), frames[part] if len(frames) else frames)

    def add_forces(
        self,
        rules,
        X_base,
        X_extra,
        u_base,
        u_extra,
        f_base,
        f_extra,
        update: bool = True,
        part: str | int | slice = "all",
        corotational: bool = False,
    ) -> float:
        """Add the elements' internal forces (N) into ``f_base``, ``f_extra`` (n, 3), updating
        the damage state (``update`` False: at the damage as it is); ``rules``: the packed
        rules (``RuleTable.packed``); X, u in mm; ``part``: "all", "interior" or "boundary"
        elements, chunk k of the interior (``set_elements``), or a slice of all of them (for
        profiling: it copies them); ``corotational``: each element
        in its co-rotated frame (finite kinematics). Returns their secant strain energy (mJ,
        this rank)."""
        elements = self._part(part) if isinstance(part, slice) else self._parts[part]
        return add_damaged_subelement_forces(
            *elements[:4],
            *rules,
            *self.pack,
            self.band_width,
            self.damage,
            X_base,
            X_extra,
            u_base,
            u_extra,
            f_base,
            f_extra,
            update,
            corotational,
            self.erode,
            self.min_volume_ratio,
            self.eroded_count,
            elements[4],
        )

    def scale_matrix_strength(self, cells: np.ndarray, plies: Iterable[int], factor: float) -> None:
        """Let the matrix of these plies (0-based) in these owned cells crack at ``factor`` times
        the transverse strength: sets the ply's crack-onset energy to (factor YT)^2 / (2 C22)."""
        for k in plies:
            ply = self.laminate.plies[k]
            C22 = ply.material.stiffness()[1, 1]
            YT = self.failures[ply.material.name].YT
            self.damage[cells, k, S_Y0] = (factor * YT) ** 2 / (2.0 * C22)

    def eroded(self, cells: np.ndarray, spans: np.ndarray) -> np.ndarray:
        """(n,) bool: which of the elements of owned ``cells`` holding plies ``spans`` (n, 2)
        [first, stop) erosion has removed (all their plies' fibres broken; none without
        ``erode``)."""
        gone = np.zeros(len(cells), dtype=bool)
        if self.erode and len(cells):
            elements_eroded(
                self.damage,
                np.asarray(cells, dtype=np.int64),
                np.asarray(spans, dtype=np.int64).reshape(-1, 2),
                gone,
            )
        return gone

    def eroded_elements(self) -> int:
        """How many of this rank's (sub)elements erosion has removed (``eroded``)."""
        if not self.elements:
            return 0
        return int(np.count_nonzero(self.eroded(self.elements[2], self._spans)))

    def base_node_carriers(self, n_base: int) -> np.ndarray:
        """(n_base,) int: for each local base node (owned and ghost), how many of this rank's
        elements hold it and have not eroded."""
        nodes, _, cells = self.elements[:3]
        held = nodes[~self.eroded(cells, self._spans)].ravel()
        return np.bincount(held[held < n_base], minlength=n_base)

    def extra_node_carriers(self, n_base: int, n_extra: int) -> np.ndarray:
        """(n_extra,) int: for each local extra node (owned and ghost; combined index n_base +
        its own), how many of this rank's elements hold it and have not eroded."""
        nodes, _, cells = self.elements[:3]
        held = nodes[~self.eroded(cells, self._spans)].ravel()
        return np.bincount(held[held >= n_base] - n_base, minlength=n_extra)[:n_extra]

    def _integral(self, slot: int) -> float:
        """A density slot of the state (MPa = mJ/mm^3) times the plies' volumes: mJ, this
        rank."""
        return dot(self.damage[:, :, slot].ravel(), self.ply_volumes.ravel())

    def dissipated_energy(self) -> float:
        """Energy (mJ) the damage (matrix and fibre) of this rank's plies dissipated so far."""
        return self._integral(S_DISSIPATED)

    def fibre_dissipated_energy(self) -> float:
        """The fibres' share (mJ) of ``dissipated_energy``."""
        return self._integral(S_FIBRE_DISSIPATED)

    def eroded_energy(self) -> float:
        """Strain energy (mJ) this rank's elements held when erosion removed them."""
        return self._integral(S_ERODED)

    def state(self) -> dict[str, np.ndarray]:
        """{"damage": the (n_cells, n_plies, N_STATE) state}."""
        return {"damage": self.damage}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Put back the damage state of ``state`` (as ``state`` gives it), in place (the kernel
        arguments keep pointing at it). Raises ValueError for a state of another shape (a
        checkpoint written by a version with other state slots)."""
        damage = state["damage"]
        if damage.shape != self.damage.shape:
            raise ValueError(
                f"ply damage state of shape {damage.shape}, this model's is {self.damage.shape}: "
                "the checkpoint was written by another version of the ply damage law"
            )
        self.damage[:] = damage
