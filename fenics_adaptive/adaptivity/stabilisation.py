"""The state of the paper's remedies for the sudden change of internal forces on refinement:
damping windows after weak refinements, tie forces after strong ones (the user's parameters are
the ``Stabilisation`` settings).

Units: N, mm, s, tonne.

A refinement tells ``StabilisationState`` what it would stabilise (``request``: newly weakly
refined cells, new strong node pairs); right after it, ``start`` opens the damping windows and
sets the tie forces. The solver asks each step for the active windows (``active_damping``) and
adds the tie forces (``add_tie_forces``). ``state`` / ``restore`` carry the windows and ties
through a checkpoint (the requests never outlive a step, so they are not part of it).

A tie force stands for the traction the continuous interface carried when it split, which the
new cohesive element takes over as the tie fades (Menouillard & Belytschko 2010). That traction
resisted one relative motion of the pair; a fixed force would go on pushing whatever the pair
then does, and push an interface open once the load on it has turned round (measured: 36.5 mJ
put into a struck beam whose impactor brought 36 mJ). So a tie follows its pair
(``TieRelease``, ``tie_weight``), over its reach r = |T0| / (K A), the opening at which the
pair's cohesive element (penalty K, the pair's interface area A) carries the tie's force: full
while the pair has moved against the force by up to r (the hand-over: as the tie fades the
cohesive element takes its force over), let go as the pair opens on to the law's final opening
(the crack opens under it: the tie softens as the interface's own law does). Once the pair
moves the other way, along the force (the load has turned round), the tie pushes with at most
what the element carries at its onset and lets go over ten times that opening: it stops short
of the onset, so the element does not start to soften under it, and its stiffness there is a
tenth of the element's (the stable step holds). At a given scale the force depends on the
pair's position alone: as the scale falls a tie can put in at most 5 K A onset^2 per pair.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI
from numba import njit

from fenics_adaptive.settings.materials import P_GIC, P_GIIC, P_KN, P_KS, P_N, P_S

if TYPE_CHECKING:
    from fenics_adaptive.settings.adaptivity import Stabilisation


# a pair that has moved along its tie's force by less than this share of the smaller of its
# reach and the law's onset has not moved: a tie holds its pair as the continuous interface
# did (``tie_forces``), so that at first its motion along the force is round-off, whose sign
# differs with the summation order (the rank count); deciding the branch on it parted 1- and
# 2-rank runs of a struck plate by 3.6 % in peak force
TIE_SLACK = 1e-9
# how much longer than its reach a tie takes to let go of a pair that moves along its force:
# its stiffness there, s |T0| / (ALONG r) = s K A / ALONG, stays a tenth of its cohesive
# element's, whose spring the stable step already holds with the safety factor's margin (the
# pair's eigenvalue rises by at most a tenth: its step by 5 %)
ALONG = 10.0


@dataclass(frozen=True)
class TieRelease:
    """How a tie lets go of its pair, from the cohesive law of the interface it ties:
    ``stiffness`` (N/mm^3), the law's stiffer penalty K = max(K_n, K_s), ``onset`` (mm), its
    smaller onset opening, min(N / K_n, S / K_s), and ``final`` (mm), its larger final
    opening, max(2 GIc / N, 2 GIIc / S). A pair whose lower node holds an interface area A
    (its share of the cohesive elements around it) has the reach r = |T0| / (K A), the opening
    at which its cohesive element carries the tie's force (``reach``, ``tie_weight``). The
    default, a stiffness of 0, is a tie that never lets go (a fixed force that only fades)."""

    stiffness: float = 0.0
    onset: float = math.inf
    final: float = math.inf

    def __post_init__(self) -> None:
        if not (self.stiffness >= 0.0 and 0.0 < self.onset <= self.final):
            raise ValueError(
                f"stiffness >= 0, 0 < onset <= final (got {self.stiffness}, {self.onset}, "
                f"{self.final})"
            )

    @classmethod
    def of_law(cls, params: np.ndarray | None) -> TieRelease:
        """The release of ties on interfaces of the cohesive law ``params``
        (``CohesiveLaw.as_array``; None: no law, ties that never let go)."""
        if params is None or not params[P_KN] > 0.0:
            return cls()
        onset = min(params[P_N] / params[P_KN], params[P_S] / params[P_KS])
        final = max(2.0 * params[P_GIC] / params[P_N], 2.0 * params[P_GIIC] / params[P_S])
        return cls(float(max(params[P_KN], params[P_KS])), float(onset), float(max(final, onset)))

    def reach(self, force: np.ndarray, area: np.ndarray) -> np.ndarray:
        """(n,) mm: each tie's reach r = |T0| / (K A) from its force T0 (n, 3) N and its
        pair's interface area A (n,) mm^2; inf (never let go) without a stiffness or an
        area."""
        spring = self.stiffness * np.asarray(area, dtype=float)
        size = np.linalg.norm(force, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(spring > 0.0, size / spring, np.inf)


@njit(cache=True)
def tie_weight(along: float, reach: float, onset: float, final: float) -> float:
    """The share (0 to 1) of its force a tie of ``reach`` r applies when its pair has moved
    ``along`` (mm) in the force's direction since it was tied. Against the force (along < 0):
    1 on [-r, 0], the hand-over (the cohesive element takes the force over as the pair opens
    against it by up to r), falling linearly to 0 at -``final`` as the pair opens on (the tie
    softens as the cohesive law does; at once if r >= final). Along the force (the load has
    turned round): at most what the cohesive element carries at its ``onset``, c = min(1,
    onset / r), falling linearly to 0 over ``ALONG`` c r: pushing the pair it stops short of
    the element's onset, and its stiffness is a tenth of the element's. (Past a tie held above
    the element's strength, at a crack's tip or under an impactor, the share drops from 1 to c
    as the pair passes where it was tied: the excess is the element's penalty's to carry. A
    motion below ``TIE_SLACK`` of the smaller of r and the onset is no motion: round-off.)"""
    if along > TIE_SLACK * min(reach, onset):
        if reach <= 0.0:
            return 0.0
        held = min(1.0, onset / reach)
        return held * max(0.0, 1.0 - along / (ALONG * held * reach))
    if -along <= reach:
        return 1.0
    if final > reach:
        if math.isinf(final):
            return 1.0
        return max(0.0, (final + along) / (final - reach))
    return 0.0


@njit(cache=True)
def add_tie_group(
    f, u, a, b, force, reach, scale, onset, final, origin, last_weight, last_gap, booked
):
    """Add the forces of one group of ties at ``scale`` (its fading, 0 to 1) into f (n, 3) N,
    +w T0 on node a, -w T0 on node b, w = scale x ``tie_weight`` (of each pair's ``reach``
    (n,) mm) of the pair's motion along T0 (``force`` (n, 3) N) since it was tied, from its
    gap u_a - u_b (mm) then, ``origin`` (n, 3), which a first call (``booked`` False) sets.
    u (n_nodes, 3) mm; empty: the forces of the pairs where the last call saw them (as tied
    before any), nothing booked or kept. With ``booked``, returns the work (mJ) the
    ties did on the pairs' relative motion since ``last_gap`` at the weights ``last_weight``
    of the last call (trapezoidal, as the solver's external work, of which it is a part); both
    are updated in place."""
    work = 0.0
    looked = u.shape[0] == 0  # (the force only: nothing booked, nothing kept)
    for i in range(a.shape[0]):
        ia, ib = a[i], b[i]
        tx, ty, tz = force[i, 0], force[i, 1], force[i, 2]
        if looked:
            seen = last_gap if booked else origin
            gx, gy, gz = seen[i, 0], seen[i, 1], seen[i, 2]
        else:
            gx = u[ia, 0] - u[ib, 0]
            gy = u[ia, 1] - u[ib, 1]
            gz = u[ia, 2] - u[ib, 2]
            if not booked:
                origin[i, 0], origin[i, 1], origin[i, 2] = gx, gy, gz
        size = math.sqrt(tx * tx + ty * ty + tz * tz)
        along = 0.0
        if size > 0.0:
            along = tx * (gx - origin[i, 0]) + ty * (gy - origin[i, 1]) + tz * (gz - origin[i, 2])
            along /= size
        weight = scale * tie_weight(along, reach[i], onset, final)
        if booked and not looked:
            moved = tx * (gx - last_gap[i, 0]) + ty * (gy - last_gap[i, 1])
            moved += tz * (gz - last_gap[i, 2])
            work += 0.5 * (last_weight[i] + weight) * moved
        if not looked:
            last_weight[i] = weight
            last_gap[i, 0], last_gap[i, 1], last_gap[i, 2] = gx, gy, gz
        if weight > 0.0:
            f[ia, 0] += weight * tx
            f[ia, 1] += weight * ty
            f[ia, 2] += weight * tz
            f[ib, 0] -= weight * tx
            f[ib, 1] -= weight * ty
            f[ib, 2] -= weight * tz
    return work


@dataclass
class DampingWindow:
    """Extra mass-proportional damping ``coefficient`` (1/s) on owned DOFs of a block until
    ``until`` (s)."""

    block: int
    dofs: np.ndarray
    coefficient: float
    until: float


_LOOK = np.zeros((0, 3))  # ``add_tie_group``'s u for the forces alone, nothing booked


@dataclass
class Ties:
    """Tie forces on owned extra-node pairs (lower node A, upper node B of a new strong
    interface): +w T0 on A, -w T0 on B, w = scale(t) x the pair's ``tie_weight``, scale falling
    from 1 at ``start`` to 0 at ``start + window``. ``origin`` (n, 3) mm: each pair's
    u_A - u_B when tied (set at the first evaluation); ``last_weight`` (n,), ``last_gap``
    (n, 3) mm: its w and u_A - u_B at the last evaluation that booked their work (``booked``:
    there was one)."""

    a: np.ndarray  # owned extra local indices
    b: np.ndarray
    force: np.ndarray  # (n, 3) N
    start: float
    window: float
    reach: np.ndarray | None = None  # (n,) mm (``TieRelease.reach``); None: inf, never let go
    origin: np.ndarray | None = None
    last_weight: np.ndarray | None = None
    last_gap: np.ndarray | None = None
    booked: bool = False

    def __post_init__(self) -> None:
        if self.reach is None:
            self.reach = np.full(len(self.a), np.inf)
        if self.origin is None:
            self.origin = np.zeros((len(self.a), 3))
        if self.last_weight is None:
            self.last_weight = np.zeros(len(self.a))
        if self.last_gap is None:
            self.last_gap = np.zeros((len(self.a), 3))

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

    def __init__(self, settings: Stabilisation, comm: MPI.Comm, release: TieRelease | None = None):
        """``release``: how far a tied pair may move before its tie lets go (default: never,
        ``TieRelease``)."""
        self.settings = settings
        self.comm = comm
        self.release = release or TieRelease()
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
        extra_force_and_mass: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]],
    ) -> None:
        """Collective, right after a refinement at time t (s): open the damping window of the
        requested cells' nodes and set the tie forces of the requested pairs.
        ``dofs_of_cells(cells)``: owned DOFs (base block, extra block) of the nodes of owned
        cells (collective); ``extra_force_and_mass()``: the refined structure's internal force
        less the face loads (n, 3) N, lumped mass (n,) tonne and interface area (n,) mm^2 (the
        share of the cohesive elements' area around each node) of the owned extra nodes at t
        (collective; called only when some rank has a pair)."""
        settings = self.settings
        if settings.damps and self.comm.allreduce(len(self.new_weak_cells), op=MPI.SUM):
            for block, dofs in enumerate(dofs_of_cells(self.new_weak_cells)):
                self.damping_windows.append(
                    DampingWindow(block, dofs, settings.damping, t + settings.damping_window)
                )
        new_pairs = self.comm.allreduce(len(self.new_pairs), op=MPI.SUM)
        if settings.release_window > 0.0 and new_pairs:
            force, mass, area = extra_force_and_mass()
            pairs = np.array(self.new_pairs, dtype=np.int64).reshape(-1, 2)
            a, b = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
            tied = tie_forces(force, mass, a, b)
            reach = self.release.reach(tied, area[a])
            self.ties.append(Ties(a, b, tied, t, settings.release_window, reach))
        self.discard_requests()

    def add_tie_forces(
        self, t: float, f_ext_extra: np.ndarray, u_extra: np.ndarray | None = None
    ) -> None:
        """Add the active tie forces at time t (s) to the extra block's external force (owned
        DOFs, flat, N) at the extra nodes' displacements ``u_extra`` (mm, flat, owned first;
        None: the forces at the pairs' last seen positions, nothing booked) and book the ties'
        work since the last call in ``tie_work`` (``add_tie_group``): an artificial
        constraint's energy, as an hourglass control's, which the history shows. Ties released
        by t are dropped."""
        f = f_ext_extra.reshape(-1, 3)
        u = _LOOK if u_extra is None else u_extra.reshape(-1, 3)
        onset, final = self.release.onset, self.release.final
        active = []
        for tie in self.ties:
            scale = tie.scale(t)
            work = add_tie_group(
                f, u, tie.a, tie.b, tie.force, tie.reach, scale, onset, final, tie.origin,
                tie.last_weight, tie.last_gap, tie.booked,
            )  # fmt: skip
            if u_extra is not None:
                self.tie_work += work
                tie.booked = True
            if scale > 0.0:
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
            # each pair's reach, last booked weight, gap when tied and last booked gap,
            # whether each group has booked, the work so far
            "tie_reach": np.concatenate([tie.reach for tie in ties] or [np.zeros(0)]),
            "tie_last_weight": np.concatenate([tie.last_weight for tie in ties] or [np.zeros(0)]),
            "tie_origin": np.concatenate([tie.origin for tie in ties] or [np.zeros((0, 3))]),
            "tie_last_gap": np.concatenate([tie.last_gap for tie in ties] or [np.zeros((0, 3))]),
            "tie_booked": np.array([tie.booked for tie in ties], dtype=bool),
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
            if "tie_reach" in state:  # (before the release: none, ties that never let go)
                tie.reach = np.array(state["tie_reach"][start : start + n])
            if "tie_booked" in state:
                tie.booked = bool(state["tie_booked"][len(ties)])
                tie.last_weight = np.array(state["tie_last_weight"][start : start + n])
                tie.last_gap = np.array(state["tie_last_gap"][start : start + n])
                tie.origin = np.array(state["tie_origin"][start : start + n])
            elif "tie_last_scale" in state:  # (before the release: one weight, the scale)
                scale = state["tie_last_scale"][len(ties)]
                tie.booked = bool(np.isfinite(scale))
                if tie.booked:
                    tie.last_weight = np.full(n, float(scale))
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
