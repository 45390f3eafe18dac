"""The state of the paper's remedies for the sudden change of internal forces on refinement:
damping windows after weak refinements, tie forces after strong ones (the user's parameters are
the ``Stabilisation`` settings).

Units: N, mm, s, tonne.

A refinement tells ``StabilisationState`` what it would stabilise (``request``: newly weakly
refined cells, new strong node pairs); right after it, ``start`` opens the damping windows and
sets the tie forces. The solver asks each step for the active windows (``active_damping``) and
adds the tie forces (``add_tie_forces``). ``state`` / ``restore`` carry the windows and ties
through a checkpoint (the requests never outlive a step, so they are not part of it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

if TYPE_CHECKING:
    from fenics_adaptive.settings.adaptivity import Stabilisation


@dataclass
class DampingWindow:
    """Extra mass-proportional damping ``coefficient`` (1/s) on owned DOFs of a block until
    ``until`` (s)."""

    block: int
    dofs: np.ndarray
    coefficient: float
    until: float


@dataclass
class Ties:
    """Tie forces on owned extra-node pairs (lower node A, upper node B of a new strong
    interface): +scale(t) T0 on A, -scale(t) T0 on B, scale falling from 1 at ``start`` to 0 at
    ``start + window``. ``last_scale``, ``last_gap``: the scale and u_A - u_B (n, 3) mm at the
    last force evaluation that booked their work (None before the first)."""

    a: np.ndarray  # owned extra local indices
    b: np.ndarray
    force: np.ndarray  # (n, 3) N
    start: float
    window: float
    last_scale: float = 0.0
    last_gap: np.ndarray | None = None

    def scale(self, t: float) -> float:
        return max(0.0, 1.0 - (t - self.start) / self.window)


def tie_forces(force: np.ndarray, mass: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) tie force T0 (N) on node pairs (a, b) of the extra block, from its net internal
    force ``force`` (n_nodes, 3) N (f_int - f_ext of the face loads) and lumped mass ``mass``
    (n_nodes,) tonne: with T0 on a and -T0 on b, the two nodes accelerate together as the
    continuous interface did."""
    m_a, m_b = mass[a, None], mass[b, None]
    return (m_b * force[a] - m_a * force[b]) / (m_a + m_b)


class StabilisationState:
    """Damping windows and tie forces of one rank, opened after refinements with the
    parameters of ``settings`` (a ``Stabilisation``)."""

    def __init__(self, settings: Stabilisation, comm: MPI.Comm):
        self.settings = settings
        self.comm = comm
        self.damping_windows: list[DampingWindow] = []
        self.ties: list[Ties] = []
        self.tie_work = 0.0  # mJ, this rank's: the work the ties did on the structure so far
        self.discard_requests()

    def discard_requests(self) -> None:
        """Forget what the last refinement would stabilise (a restart replaying refinements
        restores the stabilisation state it stored instead)."""
        self.new_weak_cells = np.zeros(0, dtype=np.int64)
        self.new_pairs: list[tuple[int, int]] = []

    def request(self, new_weak_cells: np.ndarray) -> None:
        """A refinement begins: damp the nodes of these newly weakly refined owned cells; the
        new strong pairs follow through ``request_pair``."""
        self.new_weak_cells = new_weak_cells
        self.new_pairs = []

    def request_pair(self, a: int, b: int) -> None:
        """Tie the owned extra nodes a (set A) and b (set B) of a new strong interface."""
        self.new_pairs.append((a, b))

    def start(
        self,
        t: float,
        dofs_of_cells: Callable[[np.ndarray], list[np.ndarray]],
        extra_force_and_mass: Callable[[], tuple[np.ndarray, np.ndarray]],
    ) -> None:
        """Collective, right after a refinement at time t (s): open the damping window of the
        requested cells' nodes and set the tie forces of the requested pairs.
        ``dofs_of_cells(cells)``: owned DOFs (base block, extra block) of the nodes of owned
        cells (collective); ``extra_force_and_mass()``: the refined structure's internal force
        less the face loads (n, 3) N and lumped mass (n,) tonne of the owned extra nodes at t
        (collective; called only when some rank has a pair)."""
        settings = self.settings
        if settings.damps and self.comm.allreduce(len(self.new_weak_cells), op=MPI.SUM):
            for block, dofs in enumerate(dofs_of_cells(self.new_weak_cells)):
                self.damping_windows.append(
                    DampingWindow(block, dofs, settings.damping, t + settings.damping_window)
                )
        new_pairs = self.comm.allreduce(len(self.new_pairs), op=MPI.SUM)
        if settings.release_window > 0.0 and new_pairs:
            force, mass = extra_force_and_mass()
            pairs = np.array(self.new_pairs, dtype=np.int64).reshape(-1, 2)
            a, b = pairs[:, 0], pairs[:, 1]
            self.ties.append(Ties(a, b, tie_forces(force, mass, a, b), t, settings.release_window))
        self.discard_requests()

    def add_tie_forces(
        self, t: float, f_ext_extra: np.ndarray, u_extra: np.ndarray | None = None
    ) -> None:
        """Add the active tie forces at time t (s) to the extra block's external force (owned
        DOFs, flat, N); ties released by t are dropped. With the extra nodes' displacements
        ``u_extra`` (mm, flat, owned first) the ties' work since the last call is booked in
        ``tie_work``: 1/2 (s_prev + s) T0 . ((u_A - u_B) - (u_A - u_B)_prev), trapezoidal as
        the solver's external work, of which it is a part. A tie's force is fixed at the
        refinement and fades: whatever relative motion the pair then makes, it does work on it,
        out of the structure where it holds an opening, into it where the pair moves along the
        force: an artificial constraint's energy (as an hourglass control's), which the history
        shows (``tie_work``)."""
        f = f_ext_extra.reshape(-1, 3)
        u = None if u_extra is None else u_extra.reshape(-1, 3)
        active = []
        for tie in self.ties:
            scale = tie.scale(t)
            if u is not None:
                gap = u[tie.a] - u[tie.b]
                if tie.last_gap is not None:
                    moved = np.sum(tie.force * (gap - tie.last_gap))
                    self.tie_work += 0.5 * (tie.last_scale + scale) * float(moved)
                tie.last_scale, tie.last_gap = scale, gap
            if scale > 0.0:
                np.add.at(f, tie.a, scale * tie.force)
                np.subtract.at(f, tie.b, scale * tie.force)
                active.append(tie)
        self.ties = active

    def active_damping(self, t: float) -> list[DampingWindow]:
        """The damping windows still open at time t (s); closed ones are dropped."""
        self.damping_windows = [w for w in self.damping_windows if w.until > t]
        return self.damping_windows

    def state(self) -> dict[str, np.ndarray]:
        """The ties and windows as flat arrays (checkpoint keys ``tie_*``, ``window_*``)."""
        ties, windows = self.ties, self.damping_windows
        return {
            "tie_counts": np.array([len(tie.a) for tie in ties], dtype=np.int64),
            "tie_a": np.concatenate([tie.a for tie in ties] or [np.zeros(0, np.int64)]),
            "tie_b": np.concatenate([tie.b for tie in ties] or [np.zeros(0, np.int64)]),
            "tie_force": np.concatenate([tie.force for tie in ties] or [np.zeros((0, 3))]),
            "tie_times": np.array([[tie.start, tie.window] for tie in ties]).reshape(-1, 2),
            # the last booked scale (NaN: none yet) and gaps, the work so far
            "tie_last_scale": np.array(
                [tie.last_scale if tie.last_gap is not None else np.nan for tie in ties]
            ),
            "tie_last_gap": np.concatenate(
                [tie.last_gap if tie.last_gap is not None else tie.force * np.nan for tie in ties]
                or [np.zeros((0, 3))]
            ),
            "tie_work": np.array(self.tie_work),
            "window_counts": np.array([len(w.dofs) for w in windows], dtype=np.int64),
            "window_dofs": np.concatenate([w.dofs for w in windows] or [np.zeros(0, np.int32)]),
            "window_values": np.array([[w.block, w.coefficient, w.until] for w in windows]).reshape(
                -1, 3
            ),
        }

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Put back the ties and windows of ``state`` (as ``state`` gives them)."""
        ties, start = [], 0
        for n, (t0, window) in zip(state["tie_counts"], state["tie_times"], strict=True):
            a = state["tie_a"][start : start + n]
            b = state["tie_b"][start : start + n]
            force = state["tie_force"][start : start + n]
            tie = Ties(a, b, force, float(t0), float(window))
            if "tie_last_gap" in state:  # (a checkpoint from before the ties' work: none)
                scale = state["tie_last_scale"][len(ties)]
                if np.isfinite(scale):
                    tie.last_scale = float(scale)
                    tie.last_gap = np.array(state["tie_last_gap"][start : start + n])
            ties.append(tie)
            start += n
        self.ties = ties
        self.tie_work = float(state.get("tie_work", 0.0))
        windows, start = [], 0
        for n, (block, coefficient, until) in zip(
            state["window_counts"], state["window_values"], strict=True
        ):
            dofs = state["window_dofs"][start : start + n].astype(np.int32)
            windows.append(DampingWindow(int(block), dofs, float(coefficient), float(until)))
            start += n
        self.damping_windows = windows
