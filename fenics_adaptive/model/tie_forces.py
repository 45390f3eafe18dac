"""The tie forces of new strong interfaces as a force contributor.

Units: N, mm, s, tonne.

After a strong refinement the structure holds each new node pair together by a tie force that
it releases linearly to zero, and sooner where the pair moves on (``TieRelease``:
``Structure.start_stabilisation``, ``StabilisationState.add_tie_forces``). The tie forces act
on the extra nodes as external forces; they store no energy, and the work they do (a part of
the external work: an artificial constraint's, mostly taken out where a tie holds a pair as
the cohesive element takes over, at most 5 K A onset^2 put in per pair) is the history's
``tie_work``. Their state (which pairs, which force, since when, the work so far) belongs to
the structure's stabilisation state and is checkpointed with it, so this contributor keeps
none of its own.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fenics_adaptive.adaptivity.stabilisation import StabilisationState
from fenics_adaptive.model.forces import Contributor, ForceKind


class TieForces(Contributor):
    """The active tie forces of ``stabilisation``, added to the extra nodes' external force."""

    name = "ties"
    kind = ForceKind.EXTERNAL

    def __init__(self, stabilisation: StabilisationState, displacement: Callable[[], np.ndarray]):
        """``displacement()``: the extra nodes' displacements now (mm, flat, owned first)."""
        self.stabilisation = stabilisation
        self.displacement = displacement

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add the tie forces at time t (s) into ``f_extra`` (N, owned extra DOFs, flat) and
        book their work since the last call."""
        if self.stabilisation.ties:
            self.stabilisation.add_tie_forces(t, f_extra, self.displacement())
