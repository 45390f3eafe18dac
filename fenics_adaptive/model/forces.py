"""The one interface of everything that puts a nodal force on the structure.

Units: N, mm, s, tonne (forces N, energies mJ = N mm).

The solver sums the contributors every step. Each one says where its force goes (``kind``),
because the energy balance books them differently: an INTERNAL force (solid, subelements,
cohesive elements, the border transfer of constrained extra nodes) does internal work, an
EXTERNAL one (face loads, tie forces of a new strong interface) external work, and a CONTACT
force (a rigid impactor) is work the impactor gives up (``impact_work``).
"""

from __future__ import annotations

from enum import Enum
from typing import Protocol, runtime_checkable

import numpy as np


class ForceKind(Enum):
    """Where a contributor's force goes in the balance of momentum and of energy."""

    INTERNAL = "internal"  # into f_int: its work is internal work
    EXTERNAL = "external"  # into f_ext: its work is external work
    CONTACT = "contact"  # on the base DOFs beside f_ext: work the impactor gives up


@runtime_checkable
class ForceContributor(Protocol):
    """A source of nodal force, with the energy it stores and the state it keeps."""

    name: str
    kind: ForceKind

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add this contributor's force at time t (s) into this rank's base and extra DOF
        arrays (N, flat; the explicit solver passes the owned entries)."""
        ...

    def energy(self) -> float:
        """mJ: the energy it stores now (strain, recoverable cohesive, penalty), this rank's
        share."""
        ...

    def state(self) -> dict[str, np.ndarray]:
        """What a restart needs to continue it exactly, as named arrays (scalars 0-d)."""
        ...

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from ``state()`` taken from the same contributor on the same rank."""
        ...


class Contributor:
    """Base of a contributor with the solver's optional hooks, all no-ops: subclass it and
    define ``name``, ``kind`` and the four methods of ``ForceContributor``."""

    name: str = ""
    kind: ForceKind = ForceKind.EXTERNAL

    def energy(self) -> float:
        return 0.0

    def state(self) -> dict[str, np.ndarray]:
        return {}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        pass

    def prepare(self, dt: float, element_step: float) -> None:
        """The time step dt (s) was chosen at the start of a run; ``element_step``: the
        structure's stable step without the safety factor (s). A contributor that limits the
        step (a penalty) checks itself here."""

    def advance(self, mean_dt: float, dt: float) -> None:
        """The structure moved from t_n to t_n + dt (s); ``mean_dt``: (dt_{n-1/2} + dt) / 2
        (s). A contributor with degrees of freedom of its own (a rigid impactor) integrates
        them here with the same central-difference scheme."""

    def report(self, row, first: bool) -> None:
        """Fill this contributor's columns of a history row (``explicit.HistoryRow``);
        ``first``: the row at t = 0."""

    def suspect(self) -> str:
        """What of this contributor to suspect when a run blows up ("" for nothing)."""
        return ""
