"""Physics guards of the explicit run: an inverted element and a broken energy balance stop it.

Units: N, mm, s, tonne (energies in mJ).

Inversion. An element inverts when the Jacobian of its CURRENT configuration, J = dx/dxi with
x = X + u, changes sign at one of its integration points: det F = det J(x) / det J(X) <= 0 (for
small strain the same test on the current geometry: a small-strain element that has inverted is
as meaningless as a finite-strain one). One jitted check covers every solid (sub)element of
the rank, whichever path computes its force (ESL cells through the UFL forms, LW cells,
subelements of refined cells, damage-aware cells): it reads the nodes of each element
(``Structure.elements``) and the points of its packed rule (``Structure.element_rules``), so
it never drifts from the force kernels' point sets and costs the force kernels nothing. The
solver runs it at its poll (every 64 steps) and on output steps.

On one vertical line (xi, eta) of a trilinear hexahedron, dx/dxi and dx/deta are affine in zeta
and dx/dzeta is constant, so det J is a quadratic in zeta: its three coefficients are formed once
per line and evaluated at every point of the line (about 600 flops per element in all).

Energy balance. The run stops when |energy_balance| exceeds ``limit`` times the largest energy
of the run so far: the largest of the energy at t = 0 (kinetic + strain + stored cohesive +
the impactor's kinetic and penalty energy) and, over every history row up to now, |external
work|, |impact work|, kinetic energy and |internal work| (a scale that never decreases, so a
run whose energies fall back, a rebound, is judged against what it held). The energy at t = 0
is one floor: ``impact_work`` is the difference of two values of the impactor's energy (625 mJ
in the plate impact demo), whose round-off, 1e-4 mJ there, is 98 % of the energy transferred
at the first contact (step 24) and would trip the guard at the first touch. The other floor:
rows before step ``ENERGY_MIN_STEPS`` are not judged: over the first steps every energy is a
few steps' worth of work, against which the round-off of larger terms (an impactor's energy,
the forces of a stiff penalty) is not yet small. The balance itself closes to round-off
(``explicit``'s module docstring): what trips this guard is energy that nothing books, a force
whose work no one reports, a material that creates energy.
A non-finite balance always trips it.

Divergence. A run whose |kinetic energy| exceeds ``RUNAWAY`` times the work ever put in, or
whose solution is no longer finite, stops as ``Diverged``. An unstable step is caught here, not
by the energy guard: the scheme's energy identity holds at any step, so a growing mode shows as
a kinetic energy (as the scheme measures it, of either sign) that dwarfs the work put in.

``RunGuards`` raises each of these stops with its message written once, from the run's state at
t_n (time, step, time steps, where the fastest node is, what to suspect).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
from mpi4py import MPI
from numba import njit

from fenics_adaptive.model.diagnostics import describe_dof

if TYPE_CHECKING:
    from fenics_adaptive.model.forces import ForceContributor
    from fenics_adaptive.model.structure import Structure
    from fenics_adaptive.settings.solver import SolverSettings
    from fenics_adaptive.solver.blocks import BlockState
    from fenics_adaptive.solver.explicit import SolverState
    from fenics_adaptive.solver.history import HistoryRow

# the energy guard judges from this step on (see the module docstring)
ENERGY_MIN_STEPS = 100
RUNAWAY = 100.0  # kinetic energy beyond this multiple of the work put in means instability


class Diverged(RuntimeError):
    """The run blew up (or broke a physics guard): it stops as failed."""


class ElementInverted(Diverged):
    """An element inverted (det F <= 0 at an integration point): the run stops as failed."""


class EnergyBalanceError(Diverged):
    """|energy_balance| beyond ``SolverSettings.energy_error_limit`` x the largest energy."""


@njit(cache=True, inline="always")
def _monomial_coefficients(x, b):
    """b (8, 3): coefficients of x(xi, eta, zeta) = sum_m b_m xi^(m&1) eta^((m>>1)&1)
    zeta^((m>>2)&1) from the vertex values x (8, 3) (vertex k at (k&1, (k>>1)&1, (k>>2)&1))."""
    for i in range(3):
        # three butterfly stages (differences along xi, eta, zeta), written out
        x0, x1, x2, x3 = x[0, i], x[1, i], x[2, i], x[3, i]
        x4, x5, x6, x7 = x[4, i], x[5, i], x[6, i], x[7, i]
        d1, d3, d5, d7 = x1 - x0, x3 - x2, x5 - x4, x7 - x6
        b[0, i] = x0
        b[1, i] = d1
        b[2, i] = x2 - x0
        b[3, i] = d3 - d1
        b[4, i] = x4 - x0
        b[5, i] = d5 - d1
        b[6, i] = (x6 - x4) - (x2 - x0)
        b[7, i] = (d7 - d5) - (d3 - d1)


@njit(cache=True, inline="always")
def _line_determinant(b, xi, eta):
    """(c0, c1, c2) with det J(xi, eta, zeta) = c0 + c1 zeta + c2 zeta^2 for the map b."""
    # dx/dxi = a0 + zeta a1, dx/deta = e0 + zeta e1, dx/dzeta = c (scalars: no allocation)
    a00, a01, a02 = b[1, 0] + eta * b[3, 0], b[1, 1] + eta * b[3, 1], b[1, 2] + eta * b[3, 2]
    a10, a11, a12 = b[5, 0] + eta * b[7, 0], b[5, 1] + eta * b[7, 1], b[5, 2] + eta * b[7, 2]
    e00, e01, e02 = b[2, 0] + xi * b[3, 0], b[2, 1] + xi * b[3, 1], b[2, 2] + xi * b[3, 2]
    e10, e11, e12 = b[6, 0] + xi * b[7, 0], b[6, 1] + xi * b[7, 1], b[6, 2] + xi * b[7, 2]
    xe = xi * eta
    c0_ = b[4, 0] + xi * b[5, 0] + eta * b[6, 0] + xe * b[7, 0]
    c1_ = b[4, 1] + xi * b[5, 1] + eta * b[6, 1] + xe * b[7, 1]
    c2_ = b[4, 2] + xi * b[5, 2] + eta * b[6, 2] + xe * b[7, 2]
    c0 = _triple(a00, a01, a02, e00, e01, e02, c0_, c1_, c2_)
    c1 = _triple(a00, a01, a02, e10, e11, e12, c0_, c1_, c2_) + _triple(
        a10, a11, a12, e00, e01, e02, c0_, c1_, c2_
    )
    c2 = _triple(a10, a11, a12, e10, e11, e12, c0_, c1_, c2_)
    return c0, c1, c2


@njit(cache=True, inline="always")
def _triple(a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """(a x b) . c of three vectors given by their components"""
    return (a1 * b2 - a2 * b1) * c0 + (a2 * b0 - a0 * b2) * c1 + (a0 * b1 - a1 * b0) * c2


@njit(cache=True)
def reference_orientation(element_nodes, X_base, X_extra):
    """Sign (+1 or -1) of det J of each element's reference geometry at its centre."""
    n_base = X_base.shape[0]
    out = np.empty(element_nodes.shape[0])
    x = np.empty((8, 3))
    b = np.empty((8, 3))
    for e in range(element_nodes.shape[0]):
        for a in range(8):
            node = element_nodes[e, a]
            for i in range(3):
                x[a, i] = X_base[node, i] if node < n_base else X_extra[node - n_base, i]
        _monomial_coefficients(x, b)
        c0, c1, c2 = _line_determinant(b, 0.5, 0.5)
        out[e] = 1.0 if c0 + 0.5 * c1 + 0.25 * c2 >= 0.0 else -1.0
    return out


@njit(cache=True)
def first_inverted_point(
    element_nodes,
    rule_of_element,
    orientation,
    line_offsets,
    line_points,
    zeta,
    position_of_point,
    positions,
    X_base,
    X_extra,
    u_base,
    u_extra,
    x,
    b,
):
    """(element, point, det) of the first integration point with orientation * det J(X + u)
    <= 0 (or not finite), (-1, -1, 0.0) if there is none. ``point`` indexes the packed rules'
    arrays; the lines of rule r are ``line_offsets[r]:line_offsets[r + 1]``, the points of line
    l ``line_points[l]:line_points[l + 1]`` (``rule_lines``). Scratch x, b: (8, 3)."""
    n_base = X_base.shape[0]
    for e in range(element_nodes.shape[0]):
        for a in range(8):
            node = element_nodes[e, a]
            if node < n_base:
                for i in range(3):
                    x[a, i] = X_base[node, i] + u_base[node, i]
            else:
                for i in range(3):
                    x[a, i] = X_extra[node - n_base, i] + u_extra[node - n_base, i]
        _monomial_coefficients(x, b)
        r = rule_of_element[e]
        sign = orientation[e]
        for line in range(line_offsets[r], line_offsets[r + 1]):
            p, end = line_points[line], line_points[line + 1]
            q = position_of_point[p]
            c0, c1, c2 = _line_determinant(b, positions[q, 0], positions[q, 1])
            c0, c1, c2 = sign * c0, sign * c1, sign * c2
            # a lower bound of the quadratic over the line's zeta range first: one test per
            # line; the points only when it fails
            lo, hi = zeta[p], zeta[end - 1]
            bound = min(c0 + lo * (c1 + lo * c2), c0 + hi * (c1 + hi * c2))
            if c2 > 0.0:
                vertex = -0.5 * c1 / c2
                if lo < vertex < hi:
                    bound = c0 - 0.25 * c1 * c1 / c2
            if bound > 0.0:
                continue
            for pp in range(p, end):
                z = zeta[pp]
                det = c0 + z * (c1 + z * c2)
                if not det > 0.0:  # also NaN
                    return e, pp, det
    return -1, -1, 0.0


def rule_lines(rule_offsets: np.ndarray, position_of_point: np.ndarray):
    """(line_offsets, line_points): the vertical lines of packed rules (runs of points on one
    in-plane position, bottom to top, as ``subelement.pack_rule`` orders them), CSR style."""
    starts = np.flatnonzero(np.diff(position_of_point, prepend=-1) != 0)
    starts = np.union1d(starts, rule_offsets[:-1])  # a rule starts a line
    line_points = np.append(starts, rule_offsets[-1]).astype(np.int64)
    line_offsets = np.searchsorted(starts, rule_offsets).astype(np.int64)
    return line_offsets, line_points


class InversionGuard:
    """The inversion check over every solid (sub)element of a structure (this rank).

    ``refresh()`` after the structure changed (refinement); ``check(t)`` returns None or the
    one-line message naming the cell, the point and the time."""

    def __init__(self, structure):
        self.structure = structure
        self._x = np.empty((8, 3))
        self._b = np.empty((8, 3))
        self.refresh()

    def refresh(self) -> None:
        s = self.structure
        self.nodes, self.cells, self.plies = s.elements()
        self.rule_of_element = s.element_rules(self.plies)
        self.rules = s.subelements.rules
        self.lines = rule_lines(self.rules.rule_offsets, self.rules.position_of_point)
        X_extra = s.extra.vectors["X"].array.reshape(-1, 3)
        self.orientation = reference_orientation(self.nodes, s.X_base, X_extra)

    def check(self, t: float) -> str | None:
        """This rank's first inverted point at time t (s) as a message, or None."""
        s = self.structure
        if not len(self.nodes):
            return None
        rules = self.rules
        kept = slice(None)
        if s.erosion:  # eroded elements carry nothing: they may turn over
            kept = np.flatnonzero(~s.ply_damage_state.eroded(self.cells, self.plies))
        e, p, det = first_inverted_point(
            self.nodes[kept],
            self.rule_of_element[kept],
            self.orientation[kept],
            *self.lines,
            rules.zeta,
            rules.position_of_point,
            rules.positions,
            s.X_base,
            s.extra.vectors["X"].array.reshape(-1, 3),
            s.base.u.x.array.reshape(-1, 3),
            s.extra.vectors["u"].array.reshape(-1, 3),
            self._x,
            self._b,
        )
        if e < 0:
            return None
        e = int(np.arange(len(self.nodes))[kept][e])
        return self.describe(t, e, int(p), float(det))

    def describe(self, t: float, e: int, p: int, det: float) -> str:
        """The message for point p (index into the packed rules) of element e."""
        s = self.structure
        cell = int(self.cells[e])
        corners = np.concatenate([s.bottom_local[cell], s.top_local[cell]])
        centroid = s.X_base[corners].mean(axis=0)
        rules = self.rules
        first, stop = int(self.plies[e, 0]), int(self.plies[e, 1])
        xi, eta = rules.positions[rules.position_of_point[p]]
        z = rules.zeta[p]
        # the ply that holds the point's height (a pre-integrated point belongs to no ply)
        f = s.laminate.ply_fractions
        height = f[first] + z * (f[stop] - f[first])
        ply = int(np.clip(np.searchsorted(f, height, side="right") - 1, first, stop - 1))
        # det F = det J(x) / det J(X) at the point
        X = s.gather(self.nodes[e], "X")
        b = np.empty((8, 3))
        _monomial_coefficients(X, b)
        c0, c1, c2 = _line_determinant(b, xi, eta)
        det_F = det / abs(c0 + z * (c1 + z * c2))
        refined = bool((s.interface_state[cell] != 0).any())
        kind = f"subelement (plies {first + 1}-{stop}) of cell" if refined else "cell"
        return (
            f"t = {t:.6g} s: element inverted: {kind} {s.original_cell[cell]} (centroid "
            f"{centroid[0]:.4g}, {centroid[1]:.4g}, {centroid[2]:.4g} mm), ply {ply + 1}, "
            f"integration point (xi, eta, zeta) = ({xi:.4g}, {eta:.4g}, {z:.4g}): "
            f"det F = {det_F:.3g} <= 0"
        )


def largest_energy(
    external_work: float, impact_work: float, kinetic: float, internal_work: float
) -> float:
    """The largest of |external work|, |impact work|, kinetic energy and |internal work| (mJ)."""
    return max(abs(external_work), abs(impact_work), abs(kinetic), abs(internal_work))


def energy_error(balance: float, largest_so_far: float, limit: float, step: int) -> bool:
    """Whether |balance| (mJ) breaks the guard: beyond ``limit`` x the largest energy of the run
    so far, from step ``ENERGY_MIN_STEPS`` on (a non-finite balance always does)."""
    if not math.isfinite(balance):
        return True
    return step >= ENERGY_MIN_STEPS and abs(balance) > limit * largest_so_far


class GuardedRun(Protocol):
    """What the guards read of a run (``explicit.ExplicitSolver``)."""

    now: SolverState  # the loop's scalars at t_n
    settings: SolverSettings
    where: str  # what limits the stable step
    blocks: Sequence[BlockState]  # the work arrays of the base and extra blocks
    structure: Structure
    contributors: Sequence[ForceContributor]
    comm: MPI.Comm


class RunGuards:
    """The run's stops as failed, each message written once, from the run's state at t_n
    (time, step, time steps, where the fastest node is, what to suspect)."""

    def __init__(self, run: GuardedRun):
        self.run = run

    def runaway(self, kinetic: float, put_in: float) -> None:
        """Collective: Diverged when the motion holds far more energy (|kinetic|, mJ) than
        was ever put in (mJ)."""
        s = self.run.now
        if s.step > 0 and kinetic > RUNAWAY * max(put_in, 1e-300):
            raise Diverged(
                f"t = {s.t:.6g} s (step {s.step}): |kinetic energy| {kinetic:.4g} mJ exceeds "
                f"{RUNAWAY:g} x the work put in ({put_in:.4g} mJ), fastest "
                f"{self.where_fastest()}: the run is unstable "
                f"(time step {s.dt:.4g} s, stable step {s.stable:.4g} s, limited by "
                f"{self.run.where}; {self.likely_cause()})"
            )

    def energy(self, row: HistoryRow) -> None:
        """Collective: EnergyBalanceError when |balance - balance at t = 0| exceeds the limit
        share of the largest energy of the run so far."""
        s, limit = self.run.now, self.run.settings.energy_error_limit
        largest = largest_energy(
            row.external_work, row.impact_work, row.kinetic_energy, row.internal_energy
        )
        s.largest_energy = max(s.largest_energy, largest)
        error = row.energy_balance - s.initial_balance
        if energy_error(error, s.largest_energy, limit, s.step):
            raise EnergyBalanceError(
                f"t = {s.t:.6g} s (step {s.step}): energy balance error {error:.4g} mJ "
                f"exceeds {limit:g} x the largest energy of the run, {s.largest_energy:.4g} "
                f"mJ (solver.energy_error_limit); fastest {self.where_fastest()}; "
                f"{self.likely_cause()}"
            )

    def not_finite(self) -> None:
        """Collective in parallel: the one Diverged of a solution that is no longer finite."""
        s = self.run.now
        raise Diverged(
            f"t = {s.t:.6g} s (step {s.step}): the solution is no longer finite "
            f"{self.where_fastest()}; time step {s.dt:.4g} s, stable step {s.stable:.4g} s"
        )

    def inverted(self, message: str | None, anywhere: bool) -> None:
        """``message``: this rank's; ``anywhere``: some rank has one (known to all ranks).
        Collective when anywhere (the message of the lowest rank that has one)."""
        if not anywhere:
            return
        if self.run.comm.size > 1:
            message = next(m for m in self.run.comm.allgather(message) if m is not None)
        raise ElementInverted(message)

    def where_fastest(self) -> str:
        """Collective: where the largest (or a non-finite) velocity is, for error messages."""
        best = (-1.0, "")
        for index, state in enumerate(self.run.blocks):
            speed = np.abs(state.v)
            speed[~np.isfinite(speed)] = np.inf
            if len(speed) and speed.max() > best[0]:
                dof = int(np.argmax(speed))
                best = (float(speed[dof]), describe_dof(self.run.structure, index, dof))
        speed, text = max(self.run.comm.allgather(best))
        return f"at {text} (|v| = {speed:.3g} mm/s)"

    def likely_cause(self) -> str:
        """Collective: what most likely made a run with a stable element step blow up (what
        the contributors suspect of themselves)."""
        causes = [c.suspect() for c in self.run.contributors if hasattr(c, "suspect")]
        return " ".join(cause for cause in causes if cause) or "an unstable time step?"
