"""The elements of the refined cells: the
subelements (with the owned cell and the plies each spans, and its dilatational wave speed) and
the cohesive elements of the strong interfaces (paper Eq. (3)).

Units: N, mm, s, tonne.

``RefinedCells.rebuild`` makes both sets anew from the refined cells' interface states after a
refinement (the cohesive damage rows persist: each strong (cell, interface) keeps its row);
``add_cohesive_forces`` adds the cohesive elements' internal forces in a step (the
subelements' go through the solids' kernel with every other solid element,
``internal_forces.ElasticSolid``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.rules import RuleTable
from fenics_adaptive.model.assembly import (
    CohesiveSet,
    SubelementSet,
    add_cohesive_forces,
)
from fenics_adaptive.settings.kinds import InterfaceState


class RefinedCells:
    """Subelements and cohesive elements of this rank's refined cells.

    Parameters: ``rule_table`` the packed rules of every ply span, ``cohesive`` the cohesive
    elements present from the start (an LW model's; else empty), ``law_params`` the cohesive
    law (``CohesiveLaw.as_array()``) of the elements refinement makes, None to keep
    ``cohesive``'s.

    Attributes: ``subelements`` (``SubelementSet``), ``cells`` (n,) the owned cell of each
    subelement, ``plies`` (n, 2) its laminate plies [first, stop), ``speeds`` (n,) its
    dilatational wave speed (mm/s), ``cohesive`` (``CohesiveSet``).
    """

    def __init__(
        self, rule_table: RuleTable, cohesive: CohesiveSet, law_params: np.ndarray | None = None
    ):
        self.rule_table = rule_table
        self.subelements = SubelementSet.empty(rule_table.packed)
        self.cells = np.zeros(0, dtype=np.int64)
        self.plies = np.zeros((0, 2), dtype=np.int64)
        self.speeds = np.zeros(0)
        self.cohesive = cohesive
        self.law_params = law_params

    def rebuild(
        self,
        refined: np.ndarray,
        states: np.ndarray,
        damage_rows: dict[tuple[int, int], int],
        subelement_nodes: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray],
        cohesive_nodes: Callable[[np.ndarray, np.ndarray], np.ndarray],
    ) -> None:
        """Both sets for the owned cells ``refined`` with interface states ``states`` (one row
        each): subelements cell by cell, bottom to top; cohesive elements at the strong
        interfaces, cells in order, interfaces bottom to top, each on the damage row
        ``damage_rows[(cell, interface)]``. ``subelement_nodes(states, first, stop, cells)``
        gives the (m, 8) nodes of subelements plies first:stop, ``cohesive_nodes(interfaces,
        cells)`` the (m, 8) nodes of cohesive elements (combined local indices)."""
        rows, first, stop = enr.subelement_table(states)
        cells = refined[rows]
        nodes = subelement_nodes(states[rows], first, stop, cells)
        spans = np.column_stack([first, stop]).astype(np.int64)
        self.subelements = SubelementSet(
            nodes, self.rule_table.rule_of(spans), self.subelements.rules
        )
        self.cells = cells.astype(np.int64)
        self.plies = spans
        self.speeds = self.rule_table.wave_speed(spans)
        rows, interface_index = np.nonzero(states == InterfaceState.STRONG)
        cells, interfaces = refined[rows], interface_index + 1
        pairs = zip(cells.tolist(), interfaces.tolist(), strict=True)
        coh_rows = [damage_rows[pair] for pair in pairs]
        self.cohesive = CohesiveSet(
            cohesive_nodes(interfaces, cells),
            np.array(coh_rows, dtype=np.int64),
            self.cohesive.damage,
            self.law_params if self.law_params is not None else self.cohesive.params,
            interfaces.astype(np.int32),
            self.cohesive.history,
            self.cohesive.insert,
        )

    def elements(
        self, nodes: np.ndarray, cells: np.ndarray, plies: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The whole cells' elements given (nodes (n, 8), owned cells (n,), plies (n, 2)), then
        the subelements: (nodes as int32, cells, plies)."""
        if len(self.subelements):
            nodes = np.vstack([nodes, self.subelements.nodes])
            cells = np.concatenate([cells, self.cells])
            plies = np.vstack([plies, self.plies])
        return nodes.astype(np.int32), cells, plies

    def add_cohesive_forces(
        self,
        X_base: np.ndarray,
        X_extra: np.ndarray,
        u_base: np.ndarray,
        u_extra: np.ndarray,
        f_base: np.ndarray,
        f_extra: np.ndarray,
    ) -> float:
        """Subtract the cohesive elements' forces (N) from ``f_base`` / ``f_extra`` (n, 3),
        updating their damage. Returns their recoverable energy (mJ)."""
        return add_cohesive_forces(self.cohesive, X_base, X_extra, u_base, u_extra, f_base, f_extra)
