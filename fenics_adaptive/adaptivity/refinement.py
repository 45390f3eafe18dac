"""Refinement bookkeeping of a structure: the state of every interface of every owned cell, when
each became weak, the cohesive damage row of each strong (cell, interface), the log of the
refinements (for restarts) and the mechanical energy they changed.

Units: s (times), mJ (energies).

``Structure.refine`` plans a refinement here (``plan``: the requests checked against the
interfaces allowed to refine or delaminate), then moves nodes and masses and marks the cells
weak or strong (``mark_weak``, ``mark_strong``) interface by interface. ``state`` /
``restore`` carry the log and the energy through a checkpoint: a restart replays the logged
refinements in order, so that everything derived from them (extra nodes, masses, maps) comes
out as it was.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.settings.kinds import InterfaceState

if TYPE_CHECKING:
    from fenics_adaptive.settings.adaptivity import Interfaces

# a refinement request: (owned local cell, interface 1 .. n_plies - 1, InterfaceState WEAK or
# STRONG)
Request = tuple[int, int, int]


class RefinementState:
    """Interface states of ``n_cells`` owned cells with ``n_interfaces`` ply interfaces each,
    refined as ``interfaces`` (an ``Interfaces``) allows."""

    def __init__(self, n_cells: int, n_interfaces: int, interfaces: Interfaces):
        self.interfaces = interfaces
        # InterfaceState.NONE, WEAK or STRONG per (owned cell, interface - 1)
        self.interface_state = np.zeros((n_cells, max(n_interfaces, 0)), dtype=np.int8)
        self.weak_since = np.full(self.interface_state.shape, np.inf)  # s
        self.strong_since = np.full(self.interface_state.shape, np.inf)  # s
        # cohesive damage row of each strong (cell, interface), in the order they opened
        self.damage_rows: dict[tuple[int, int], int] = {}
        # mechanical energy (kinetic + strain + recoverable cohesive, mJ) that refinements added
        # in total, and the potential part of the last one (the solver books it as internal
        # work, so that the dissipated energy does not jump)
        self.energy = 0.0
        self.last_potential = 0.0
        # every refinement that changed something: (t, this rank's requests), for restarts
        self.log: list[tuple[float, list[Request]]] = []

    @property
    def n_interfaces(self) -> int:
        return self.interface_state.shape[1]

    def refined_cells(self) -> np.ndarray:
        """Owned cells with at least one refined interface."""
        return np.flatnonzero((self.interface_state != InterfaceState.NONE).any(axis=1))

    def unrefined_cells(self) -> np.ndarray:
        """Owned cells with no refined interface."""
        return np.flatnonzero((self.interface_state == InterfaceState.NONE).all(axis=1))

    def plan(self, requests: Iterable[Request], comm: MPI.Comm) -> np.ndarray:
        """The interface states after ``requests`` (a copy; a strong request on an unrefined
        interface makes it strong through weak). Raises InputError, on every rank of ``comm``,
        for an interface not allowed to refine as asked."""
        target = self.interface_state.copy()
        with shared_errors(comm):  # the requests are this rank's: so may be the error
            for cell, interface, kind in requests:
                allowed = set(self.interfaces.delaminate)
                if kind != InterfaceState.STRONG:
                    allowed |= set(self.interfaces.refine)
                if interface not in allowed:
                    what = "delaminate" if kind == InterfaceState.STRONG else "refine"
                    raise InputError(
                        "interfaces", f"interface {interface} is not allowed to {what}"
                    )
                target[cell, interface - 1] = max(target[cell, interface - 1], int(kind))
        return target

    def record(self, t: float, requests: Iterable[Request]) -> None:
        """Log a refinement at time t (s) that changed something."""
        self.log.append((t, [tuple(int(x) for x in r) for r in requests]))

    def to_weaken(self, cells: np.ndarray, target: np.ndarray, interface: int) -> np.ndarray:
        """Those of ``cells`` whose ``interface`` is unrefined and becomes at least weak."""
        column = interface - 1
        return cells[
            (self.interface_state[cells, column] == InterfaceState.NONE)
            & (target[cells, column] >= InterfaceState.WEAK)
        ]

    def to_strengthen(self, cells: np.ndarray, target: np.ndarray, interface: int) -> np.ndarray:
        """Those of ``cells`` whose ``interface`` is weak and becomes strong."""
        column = interface - 1
        return cells[
            (self.interface_state[cells, column] == InterfaceState.WEAK)
            & (target[cells, column] == InterfaceState.STRONG)
        ]

    def mark_weak(self, cells: np.ndarray, interface: int, t: float = 0.0) -> None:
        """Make ``interface`` of ``cells`` weak at time t (s)."""
        self.interface_state[cells, interface - 1] = InterfaceState.WEAK
        self.weak_since[cells, interface - 1] = t

    def mark_strong(self, cells: np.ndarray, interface: int, t: float = 0.0) -> None:
        """Make ``interface`` of ``cells`` strong at time t (s), each with a new cohesive damage
        row."""
        self.interface_state[cells, interface - 1] = InterfaceState.STRONG
        self.strong_since[cells, interface - 1] = t
        for cell in np.asarray(cells).tolist():
            self.damage_rows[(cell, interface)] = len(self.damage_rows)

    def book(self, kinetic_change: float, potential_change: float) -> None:
        """Book a refinement's change of kinetic and of potential energy (mJ)."""
        self.last_potential = potential_change
        self.energy += kinetic_change + potential_change

    def book_kinetic(self, correction: float) -> None:
        """Add ``correction`` (mJ) to the booked kinetic energy change of the last refinement:
        the solver's measure of it (at full steps, with the new step) minus the structure's."""
        self.energy += correction

    def state(self) -> dict[str, np.ndarray]:
        """The log and the energy as flat arrays (checkpoint keys ``times``, ``counts``,
        ``requests``, ``energy``)."""
        log = self.log
        return {
            "times": np.array([t for t, _ in log], dtype=float),
            "counts": np.array([len(r) for _, r in log], dtype=np.int64),
            "requests": np.concatenate(
                [np.asarray(r, dtype=np.int64).reshape(-1, 3) for _, r in log] or [np.zeros((0, 3))]
            ).astype(np.int64),
            "energy": np.array(self.energy),
        }

    def restore(
        self, state: dict[str, np.ndarray], refine: Callable[[list[Request], float], object]
    ) -> None:
        """Collective: replay the logged refinements of ``state`` in order through
        ``refine(requests, t)`` (on a structure built without its initial refinement), then put
        back the energy."""
        offsets = np.concatenate([[0], np.cumsum(state["counts"])])
        for k, t in enumerate(state["times"]):
            chunk = state["requests"][offsets[k] : offsets[k + 1]]
            refine([tuple(int(x) for x in r) for r in chunk], float(t))
        self.energy = float(state["energy"])
