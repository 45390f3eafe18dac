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
        arrays (N, flat, owned + ghost entries; the owner sums the ghosts afterwards)."""
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
