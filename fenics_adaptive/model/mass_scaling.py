"""Selective mass scaling through the thickness: the scaled mass of every column of nodes.

Units: N, mm, s, tonne.

Why. A thin (sub)element's stable step is set by its thickness: the motion of its top nodes
against its bottom nodes (thickness stretch, transverse shear) is its fastest mode, and one thin
layer makes the whole model step at h / c. Selective mass scaling slows those modes alone
(Olovsson, Simonsson and Unosson 2005; Cocchetti, Pagani and Perego 2013; Confalonieri, Ghisi
and Perego 2015). With the lumped masses m, the scaled mass is

    M_s = M_L + sum_e sum_a (e_a - e_a+4)(e_a - e_a+4)^T (x) B_ea,
    B_ea = beta_t (I - n n^T) + beta_n n n^T,   beta_t = s_t,e mu_ea,   beta_n = s_n,e mu_ea,

over the four through-thickness edges (vertex a below vertex a + 4, unit vector n from one to
the other) of every solid element e, mu_ea = m_a m_a+4 / (m_a + m_a+4) the reduced mass of the
edge's two (element) lumped masses. A motion in which the two nodes of every edge move together
(a translation, membrane and in-plane motion) gets no mass: the total mass and the momentum
M_s v are unchanged. The relative motion along n (thickness stretch) is (1 + s_n) times
heavier, the relative motion across n (transverse shear, and the rotation of a column in
bending) (1 + s_t) times. The two factors are found apart because their price differs: s_n
slows through-thickness waves only, while s_t adds rotary inertia, which lowers the bending
frequencies of a coarse mesh. So s_n is the smallest factor that brings the element's largest
eigenvalue of M_s,e^-1 K_e to the target lambda_t = 4 / dt_t^2 with the shear modes held rigid,
and s_t the smallest that then brings the element there (to ``SCALING_TOLERANCE``). On a
[0/90]s plate 0.4 mm thick under 2 mm cells the thickness stretch needs s_n = 3.1, the shear
s_t = 0.62 (``tests/test_mass_scaling.py`` measures the bending frequencies).

The target step dt_t defaults to the step the in-plane size allows: the limit s -> infinity of
every element, where each edge moves rigidly, with ``IN_PLANE_MARGIN`` (the limit itself needs
an infinite mass, and the last per cent of step costs the most mass); or to twice the
cohesive springs' limit where that is shorter, since the springs and the elements share one
stable step, 1 / sqrt(1 / dt_solid^2 + 1 / dt_springs^2) (``stable_step``), and mass beyond
that buys little. An element whose own limit is above a given target aims at its own limit.

Columns. The edges join base nodes into chains through the thickness (one per column of an ESL
mesh, one per sublaminate between split boundaries of an LW mesh: a cohesive element adds no
edge); M_s is block diagonal by chain, a 3k x 3k matrix per chain of k nodes (DOF 3 slot +
component). Each chain keeps the inverse of the free part of its matrix (a prescribed DOF's
acceleration is given: the others solve M_ff a_f = r_f - M_fp a_p), computed once. The edge
blocks B are summed over the ranks as the lumped masses are (an edge's elements may lie on
several ranks), and a chain may hold ghost nodes (DOLFINx may give an edge's two nodes
different owners). The residual is never exchanged for it: a = M_s^-1 r is linear in r, so
every rank solves each chain it holds with its own share of the residual (the internal forces
of its cells, before they are summed; its owned external forces; the given accelerations of
its owned prescribed DOFs) and the shares of the accelerations travel to the owners in the
forces' reverse exchange, which a step makes anyway (``partial``, ``finish``): a step waits
twice, as with lumped masses. A force known only after that exchange (the MMB lever's hinge)
has a fixed shape: its accelerations are its size times the response to that shape
(``responses``), computed at set-up.

Stable step: lambda_max(M_s^-1 K) <= max_e lambda_max(M_s,e^-1 K_e) (the assembled masses and
stiffnesses are sums of the element ones; Rayleigh quotients), so the largest element
eigenvalue, computed exactly per element, bounds the step from the safe side. Cohesive springs
add their own eigenvalue bound (the same eigenvalues add: lambda_max(M^-1 (K_s + K_c)) <=
lambda_max(M^-1 K_s) + lambda_max(M^-1 K_c)): taking the smaller of the two steps instead, a
run with the solid elements scaled to the springs' step diverged. The springs keep their pair
limit with the lumped masses (``element.timestep.cohesive_pair_time_steps``),
not the scaled ones: with the effective masses 1 / (M_s^-1)_ii of their nodes the step of a
layerwise TCB of 0.064 mm plies rose 1.3 x further, and the run, at 0.75 of the scaled system's
true critical step, rang where the cohesive elements damaged (kinetic energy 0.03 mJ against
1e-3, the state energy balance off by 0.1 mJ of 1.4, the work-based dissipation 16 % low); at
the lumped pair limit, combined with the elements' (3.46 x the unscaled step there), it repeats
the unscaled run (peak force to 0.24 %, dissipation to 0.07 %).

Not yet: adaptive models (extra nodes) and mass-proportional damping with a scaled mass: both
are refused with an ``InputError`` (issue 17).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from dolfinx import la
from mpi4py import MPI
from numba import njit

from fenics_adaptive.element.subelement import KERNEL_OPTIONS, solid_shell_forces
from fenics_adaptive.errors import InputError
from fenics_adaptive.model.stable_step import cohesive_time_step

if TYPE_CHECKING:
    from fenics_adaptive.model.structure import Structure

# the default target eigenvalue over the largest in-plane limit of the elements (the step
# 1 / sqrt(1.25) = 0.89 of the in-plane one): the limit itself takes an infinite mass, and
# the last per cent of step the most. At 1.05 the layerwise plate impact scaled all its 10 000
# elements (shear factors up to 50) for a step 1.4 % longer than at 1.25, where none needs any
IN_PLANE_MARGIN = 1.25
# elements per block of the element eigenvalue problems (24 x 24 each: some 40 MiB a block)
ELEMENT_BLOCK = 2048
SCALING_ITERATIONS = 40
SCALING_TOLERANCE = 0.02  # on 1 + s: the factor found is at most 2 % above the smallest
# the largest factor tried, and the one that stands for "rigid" while the other is searched
MAX_SCALING = 1.0e6
# a chain whose entries across components are below this share of its largest is solved per
# component (its edges are along a coordinate axis to within round-off of the coordinates)
BANDED_TOLERANCE = 1.0e-9
# the six entries of a symmetric 3 x 3 block as the edge vectors carry them
SYMMETRIC = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


# ------------------------------------------------------------------ element level (pure)
# central-difference step of a finite-strain tangent (``element_stiffness(..., about=u)``), a
# share of the element's size
FINITE_PROBE = 1e-7


def element_stiffness(
    X: np.ndarray, rule_of_element: np.ndarray, packed, about: np.ndarray | None = None
) -> np.ndarray:
    """Stiffness matrices (n, 24, 24) N/mm of solid-shell (sub)elements with reference
    vertices ``X`` (n, 8, 3) mm, DOF 3 vertex + component; ``rule_of_element``, ``packed``: as
    ``subelement.solid_shell_forces`` takes them; symmetrised. ``about`` None: the small-strain
    kernel's, column j the force of a unit displacement of DOF j (the kernel is linear in u);
    given ((n, 8, 3) mm): the finite-strain kernel's tangent there, by central differences of
    ``FINITE_PROBE`` times the element's size."""
    n = len(X)
    X = np.ascontiguousarray(X, dtype=np.float64)
    finite = about is not None
    origin = np.zeros((n, 8, 3)) if about is None else np.asarray(about, dtype=np.float64)
    step = np.ones((n, 1))
    if finite:
        step = (FINITE_PROBE * np.abs(X - X[:, :1, :]).max(axis=(1, 2)))[:, None]
    K = np.empty((n, 24, 24))
    trial = np.empty((n, 8, 3))
    plus, minus = np.empty((n, 8, 3)), np.empty((n, 8, 3))
    for j in range(24):
        trial[:] = origin
        trial.reshape(n, 24)[:, j : j + 1] += step
        solid_shell_forces(X, trial, rule_of_element, *packed, plus, finite)
        if not finite:
            K[:, :, j] = plus.reshape(n, 24)
            continue
        trial[:] = origin
        trial.reshape(n, 24)[:, j : j + 1] -= step
        solid_shell_forces(X, trial, rule_of_element, *packed, minus, True)
        K[:, :, j] = (plus - minus).reshape(n, 24) / (2.0 * step)
    return 0.5 * (K + K.transpose(0, 2, 1))


def reduced_edge_masses(m: np.ndarray) -> np.ndarray:
    """mu_a = m_a m_a+4 / (m_a + m_a+4) (n, 4) tonne of the edges of elements with vertex
    masses ``m`` (n, 8)."""
    return m[:, :4] * m[:, 4:] / (m[:, :4] + m[:, 4:])


def edge_normals(X: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 4, 3) from vertex a to vertex a + 4 of hexahedra ``X`` (n, 8, 3)."""
    d = X[:, 4:, :] - X[:, :4, :]
    return d / np.linalg.norm(d, axis=2, keepdims=True)


def edge_blocks(normals: np.ndarray, beta_t: np.ndarray, beta_n: np.ndarray) -> np.ndarray:
    """B = beta_t (I - n n^T) + beta_n n n^T (..., 3, 3) tonne for edges with unit vectors
    ``normals`` (..., 3) and edge masses ``beta_t``, ``beta_n`` (...)."""
    nn = normals[..., :, None] * normals[..., None, :]
    return beta_t[..., None, None] * (np.eye(3) - nn) + beta_n[..., None, None] * nn


def element_scaled_mass(m: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Scaled mass matrices (n, 24, 24) tonne, DOF 3 vertex + component: diag(m) per component
    plus, for each edge (a, a+4), its block B_a (``blocks`` (n, 4, 3, 3)) as the stiffness of
    a spring between the two vertices."""
    n = len(m)
    M = np.zeros((n, 8, 3, 8, 3))
    vertices = np.arange(8)
    M[:, vertices, :, vertices, :] = m.T[:, :, None, None] * np.eye(3)
    for a in range(4):
        M[:, a, :, a, :] += blocks[:, a]
        M[:, a + 4, :, a + 4, :] += blocks[:, a]
        M[:, a, :, a + 4, :] -= blocks[:, a]
        M[:, a + 4, :, a, :] -= blocks[:, a]
    return M.reshape(n, 24, 24)


def largest_eigenvalues(K: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Largest eigenvalue (1/s^2) of M^-1 K per element, K and M (n, q, q), M positive
    definite."""
    L_inv = np.linalg.inv(np.linalg.cholesky(M))  # M = L L^T
    A = L_inv @ K @ L_inv.transpose(0, 2, 1)
    return np.linalg.eigvalsh(0.5 * (A + A.transpose(0, 2, 1)))[:, -1]


def in_plane_eigenvalues(K: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The limit of the largest eigenvalue of M_s,e^-1 K_e as the edge masses grow without end
    (1/s^2, (n,)): every edge (a, a+4) moves as one node of mass m_a + m_a+4."""
    n = len(K)
    rigid = K.reshape(n, 2, 4, 3, 2, 4, 3).sum(axis=(1, 4)).reshape(n, 12, 12)
    masses = np.repeat(m[:, :4] + m[:, 4:], 3, axis=1)  # (n, 12)
    return largest_eigenvalues(rigid, masses[:, :, None] * np.eye(12))


def smallest_factor(
    eigenvalue: Callable[[np.ndarray, np.ndarray], np.ndarray],
    aim: np.ndarray,
    floor: np.ndarray,
    start: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per element, the smallest s >= 0 (to ``SCALING_TOLERANCE`` in 1 + s) with which
    ``eigenvalue(elements, s)`` is at most ``aim`` (1/s^2), and that eigenvalue. ``floor``: its
    limit as s grows (below the aim); ``start``: its value at s = 0. Until a factor reaches the
    aim, each guess fits lambda(s) = floor + C / (1 + s) through the last value (exact for a
    single mode); then bisection in log(1 + s)."""
    s, lam = np.zeros(len(aim)), start.copy()
    low = np.zeros(len(aim))  # a factor known too small
    high = np.where(lam <= aim, 0.0, np.inf)  # the smallest known to reach the aim
    lam_high = lam.copy()
    for _ in range(SCALING_ITERATIONS):
        over = lam > aim
        low[over] = s[over]
        reached = ~over & (s <= high)
        high[reached], lam_high[reached] = s[reached], lam[reached]
        open_ = np.flatnonzero((1.0 + high) > (1.0 + SCALING_TOLERANCE) * (1.0 + low))
        if len(open_) == 0:
            break
        fit = (lam[open_] - floor[open_]) * (1.0 + s[open_])
        guess = fit / (0.99 * aim[open_] - floor[open_]) - 1.0
        s[open_] = np.where(
            np.isfinite(high[open_]),
            np.sqrt((1.0 + low[open_]) * (1.0 + high[open_])) - 1.0,
            np.minimum(np.maximum(guess, 1.05 * low[open_] + 1e-3), MAX_SCALING),
        )
        lam[open_] = eigenvalue(open_, s[open_])
    return high, lam_high


def scaling_factors(
    K: np.ndarray, m: np.ndarray, normals: np.ndarray, target: float, in_plane: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s_t, s_n, the largest eigenvalue of M_s,e^-1 K_e with them) per element (see the module
    docstring): s_n the smallest that brings the element to ``target`` (1/s^2) with its shear
    modes held rigid, then s_t the smallest with that s_n. ``in_plane``: the elements' rigid
    limits (``in_plane_eigenvalues``); an element whose limit is above the target aims at
    ``IN_PLANE_MARGIN`` times its own limit instead (it then sets the step)."""
    mu = reduced_edge_masses(m)
    n = len(K)
    aim = np.maximum(target, IN_PLANE_MARGIN * in_plane)
    rigid = np.full(n, MAX_SCALING)

    def eigenvalue(s_t: np.ndarray, s_n: np.ndarray, at: np.ndarray) -> np.ndarray:
        blocks = edge_blocks(normals[at], s_t[:, None] * mu[at], s_n[:, None] * mu[at])
        return largest_eigenvalues(K[at], element_scaled_mass(m[at], blocks))

    everything = np.arange(n)
    s_n, _ = smallest_factor(
        lambda at, s: eigenvalue(rigid[at], s, at),
        aim,
        in_plane,
        eigenvalue(rigid, np.zeros(n), everything),
    )
    s_t, lam = smallest_factor(
        lambda at, s: eigenvalue(s, s_n[at], at),
        aim,
        in_plane,
        eigenvalue(np.zeros(n), s_n, everything),
    )
    return s_t, s_n, lam


# ------------------------------------------------------------------ per step (numba)
@njit(cache=True, inline="always")
def _chain_dofs(chain_nodes, start, q, dofs):
    """The local DOFs of a chain's q = 3k entries (slot-major) into ``dofs``."""
    for i in range(q):
        dofs[i] = 3 * chain_nodes[start + i // 3] + i % 3


@njit(cache=True, inline="always")
def _given(w, prescribed, n_owned_dofs, dof):
    """The acceleration a prescribed DOF contributes on this rank: its given value where this
    rank owns it, 0 where it is a ghost (its owner contributes it)."""
    return w[dof] if prescribed[dof] and dof < n_owned_dofs else 0.0


@njit(cache=True, inline="always")
def _partial_banded(
    chain_nodes,
    start,
    q,
    factor_l,
    factor_inverse_d,
    band_diagonal,
    band_coupling,
    prescribed,
    w,
    n_owned_dofs,
    out,
    z,
):
    """``_partial_chains`` for one chain whose components do not couple, per component: the
    right-hand side less the couplings to prescribed neighbours, the LDL^T factors of the
    tridiagonal matrix (forward z_i = b_i - l_i z_i-1, backward a_i = z_i / d_i - l_i+1 a_i+1;
    a prescribed DOF's row is the identity, so it keeps its given value), then
    D_p a_p + O a_neighbours at the prescribed DOFs. ``z``: scratch (2k,)."""
    k = q // 3
    at = 3 * start
    for d in range(3):
        previous = 0.0
        for i in range(k):
            slot = at + 3 * i + d
            dof = 3 * chain_nodes[start + i] + d
            if prescribed[dof]:
                b = _given(w, prescribed, n_owned_dofs, dof)
            else:
                b = w[dof]
                if i > 0:
                    below = 3 * chain_nodes[start + i - 1] + d
                    b -= band_coupling[slot - 3] * _given(w, prescribed, n_owned_dofs, below)
                if i < k - 1:
                    above = 3 * chain_nodes[start + i + 1] + d
                    b -= band_coupling[slot] * _given(w, prescribed, n_owned_dofs, above)
            previous = b - factor_l[slot] * previous
            z[i] = previous
        a = 0.0
        for i in range(k - 1, -1, -1):
            slot = at + 3 * i + d
            following = factor_l[slot + 3] * a if i < k - 1 else 0.0
            a = z[i] * factor_inverse_d[slot] - following
            z[k + i] = a
        for i in range(k):
            dof = 3 * chain_nodes[start + i] + d
            if not prescribed[dof]:
                out[dof] = z[k + i]
                continue
            slot = at + 3 * i + d
            row = band_diagonal[slot] * z[k + i]
            if i > 0:
                row += band_coupling[slot - 3] * z[k + i - 1]
            if i < k - 1:
                row += band_coupling[slot] * z[k + i + 1]
            out[dof] = row


@njit(cache=True, **KERNEL_OPTIONS)
def _partial_chains(
    chain_offsets,
    chain_nodes,
    matrix_offsets,
    matrix,
    inverse,
    held,
    banded,
    factor_l,
    factor_inverse_d,
    band_diagonal,
    band_coupling,
    prescribed,
    w,
    n_owned_dofs,
    out,
    dofs,
    scratch,
):
    """This rank's share of the accelerations of every chain, linear in what it holds: ``w``
    (all local DOFs) holds this rank's share r_q of the residual r = f_ext - f_int at free
    DOFs and the given acceleration a_p at the prescribed DOFs it owns; a_q = G (r_q - M a_p,q)
    (a_p,q: the given accelerations of this rank's own prescribed DOFs, 0 at the others) into
    ``out`` at every local free DOF, and the row (M a_q)_p at every local prescribed DOF. The
    ranks' ``out`` summed on the owners (a reverse exchange) is the acceleration a = M^-1 r
    with the prescribed DOFs at their values, and (M_s a)_p (``finish``). ``held``: the chain
    has a prescribed DOF (the others take a = G r alone); ``banded``: its components do not
    couple (its tridiagonal factors ``factor_l``, ``factor_inverse_d`` solve it)."""
    for c in range(len(chain_offsets) - 1):
        start = chain_offsets[c]
        q = 3 * (chain_offsets[c + 1] - start)
        if banded[c]:
            _partial_banded(
                chain_nodes,
                start,
                q,
                factor_l,
                factor_inverse_d,
                band_diagonal,
                band_coupling,
                prescribed,
                w,
                n_owned_dofs,
                out,
                scratch,
            )
            continue
        at = matrix_offsets[c]
        _chain_dofs(chain_nodes, start, q, dofs)
        b, a = scratch[:q], scratch[q : 2 * q]
        for i in range(q):
            b[i] = w[dofs[i]]
        if held[c]:  # b = r - M a_p, with this rank's a_p
            for i in range(q):
                a[i] = _given(w, prescribed, n_owned_dofs, dofs[i]) if prescribed[dofs[i]] else 0.0
            for i in range(q):
                if prescribed[dofs[i]]:
                    b[i] = 0.0
                else:
                    for j in range(q):
                        b[i] -= matrix[at + i * q + j] * a[j]
        for i in range(q):
            if held[c] and prescribed[dofs[i]]:
                continue
            total = 0.0
            for j in range(q):
                total += inverse[at + i * q + j] * b[j]
            a[i] = total
        for i in range(q):
            dof = dofs[i]
            if held[c] and prescribed[dof]:
                row = 0.0
                for j in range(q):
                    row += matrix[at + i * q + j] * a[j]
                out[dof] = row
            else:
                out[dof] = a[i]


@njit(cache=True)
def _finish(out, prescribed, fixed, lumped, acc, reaction):
    """The owned accelerations from the summed shares ``out`` (free DOFs; ``acc`` keeps the
    given ones), and each reaction (the lumped m_p a_p - r_p) plus the scaled mass's share,
    (M_s a)_p - m_p a_p (``lumped``: m per owned DOF)."""
    for i in range(len(acc)):
        if not prescribed[i]:
            acc[i] = out[i]
    for k in range(len(fixed)):
        p = fixed[k]
        reaction[k] += out[p] - lumped[p] * acc[p]


@njit(cache=True, **KERNEL_OPTIONS)
def _multiply_chains(
    chain_offsets, chain_nodes, matrix_offsets, matrix, x, n_owned_dofs, out, dofs
):
    """out = M_s x on the owned DOFs of the chains (``x``: all local DOFs)."""
    for c in range(len(chain_offsets) - 1):
        start = chain_offsets[c]
        q = 3 * (chain_offsets[c + 1] - start)
        at = matrix_offsets[c]
        _chain_dofs(chain_nodes, start, q, dofs)
        for i in range(q):
            if dofs[i] >= n_owned_dofs:
                continue
            total = 0.0
            for j in range(q):
                total += matrix[at + i * q + j] * x[dofs[j]]
            out[dofs[i]] = total


# ------------------------------------------------------------------ the scaled mass
class SelectiveMass:
    """The column-wise scaled mass of a structure's base nodes (see the module docstring), built
    by ``selective_mass``. The solver's base block uses ``partial`` and ``finish`` around the
    forces' exchange (accelerations and reactions), ``responses`` for a force known only after
    it, and ``multiply`` (M_s v, for the kinetic energy); ``solve`` does all at once.

    ``chain_offsets``, ``chain_nodes``: CSR of the chains (local base nodes, bottom to top;
    every local node in one); ``matrix``: their 3k x 3k matrices (tonne), packed row by row;
    ``lumped``: the lumped mass of every local DOF; ``prescribed`` (all local DOFs), ``fixed``
    (the base block's prescribed owned DOFs, in the order of its reactions). Also kept:
    ``adds_mass`` (any element's factor above zero, on any rank), ``target_step`` (s),
    ``element_eigenvalues`` (1/s^2, each element's largest, scaled),
    ``element_cell`` (its owned cell), ``shear_scaling``, ``normal_scaling`` (s_t, s_n)."""

    def __init__(  # collective (it warms the kernels up)
        self,
        adds_mass: bool,
        index_map,
        chain_offsets: np.ndarray,
        chain_nodes: np.ndarray,
        matrix: np.ndarray,
        lumped: np.ndarray,
        prescribed: np.ndarray,
        fixed: np.ndarray,
        target_step: float,
        element_eigenvalues: np.ndarray,
        element_cell: np.ndarray,
        factors: tuple[np.ndarray, np.ndarray],
    ):
        # False where no element needed any (thick layers): M_s is then the lumped mass, and the
        # solver keeps its lumped arithmetic (the stable step is still the element bound)
        self.adds_mass = adds_mass
        self.target_step = target_step
        self.element_eigenvalues = element_eigenvalues
        self.element_cell = element_cell
        self.shear_scaling, self.normal_scaling = factors
        self.n_owned_dofs = 3 * index_map.size_local
        self.chain_offsets = chain_offsets
        self.chain_nodes = chain_nodes
        self.matrix = matrix
        self.lumped = lumped
        n_chain_dofs = 3 * len(chain_nodes)  # every local DOF, chain by chain
        sizes = 3 * np.diff(chain_offsets)
        self.matrix_offsets = np.concatenate([[0], np.cumsum(sizes**2)]).astype(np.int64)
        self.prescribed = np.asarray(prescribed, dtype=np.bool_)
        self.inverse = np.zeros(len(matrix))
        self.held = np.zeros(len(sizes), dtype=np.bool_)  # a chain with a prescribed DOF
        # chains whose components do not couple (edges along a coordinate axis) solve each
        # component's tridiagonal matrix by its LDL^T factors: per chain DOF, l and 1 / d
        self.banded = np.zeros(len(sizes), dtype=np.bool_)
        self.factor_l, self.factor_inverse_d = np.zeros(n_chain_dofs), np.zeros(n_chain_dofs)
        self.band_diagonal, self.band_coupling = np.zeros(n_chain_dofs), np.zeros(n_chain_dofs)
        for q in np.unique(sizes):
            self._invert(np.flatnonzero(sizes == q), int(q))
        if self.banded.all():  # no chain reads a dense inverse: do not keep one
            self.inverse = np.zeros(0)
        self.fixed = np.asarray(fixed, dtype=np.int64)
        self._w = la.vector(index_map, bs=3)
        largest = int(sizes.max(initial=3))
        self._scratch = np.zeros(2 * largest)
        self._dofs = np.zeros(largest, dtype=np.int64)
        # compile (or load) the per-step kernels now, at set-up, not in the first step
        zeros = np.zeros(self.n_owned_dofs)
        self.solve(zeros, np.zeros(len(fixed)))
        self.multiply(zeros, zeros.copy())

    def _invert(self, chains: np.ndarray, q: int) -> None:
        """Factorise ``chains`` (all of 3k = q DOFs): the banded ones by their components'
        tridiagonal factors, the others by the inverse of their matrix's free part."""
        at = self.matrix_offsets[chains][:, None] + np.arange(q * q)
        M = self.matrix[at].reshape(-1, q, q)
        free = ~self.prescribed[self._chain_dof_table(chains, q // 3)]
        self.held[chains] = ~free.all(axis=1)
        self._factorise_banded(chains, M, at, ~free)
        dense = ~self.banded[chains]
        if not dense.any():
            return
        M, free, at = M[dense], free[dense], at[dense]
        G = np.linalg.inv(M)
        for c in np.flatnonzero(~free.all(axis=1)):  # few: the chains a motion holds
            f = free[c]
            G[c] = 0.0
            if f.any():
                G[c][np.ix_(f, f)] = np.linalg.inv(M[c][np.ix_(f, f)])
        self.inverse[at] = G.reshape(len(G), q * q)

    def _factorise_banded(
        self, chains: np.ndarray, M: np.ndarray, at: np.ndarray, held: np.ndarray
    ) -> None:
        """Mark the ``chains`` (matrices ``M`` (n, q, q), stored at ``at``; ``held`` (n, q):
        their prescribed DOFs) whose components do not couple (edges along a coordinate axis:
        entries across components below
        ``BANDED_TOLERANCE`` of the largest, then set to zero so that every path uses the same
        matrix) and factorise each component's tridiagonal matrix with its prescribed DOFs'
        rows and columns replaced by the identity (their accelerations are given):
        d_0 = D_0, l_i = O_i-1 / d_i-1, d_i = D_i - l_i O_i-1 (D the diagonal, O the coupling to
        the next node). D and O themselves are kept for the reactions."""
        n, q = M.shape[0], M.shape[1]
        k = q // 3
        blocks = M.reshape(n, k, 3, k, 3).copy()
        across = np.broadcast_to(~np.eye(3, dtype=bool)[None, None, :, None, :], blocks.shape)
        largest = np.abs(M).max(axis=(1, 2))
        crossing = np.where(across, np.abs(blocks), 0.0).max(axis=(1, 2, 3, 4))
        banded = crossing <= BANDED_TOLERANCE * largest
        if not banded.any():
            return
        blocks[across] = 0.0
        chosen = chains[banded]
        self.matrix[at[banded]] = blocks[banded].reshape(-1, q * q)
        self.banded[chosen] = True
        kept = blocks[banded]
        D = np.einsum("nkdkd->nkd", kept)  # (m, k, 3)
        O = np.zeros_like(D)  # coupling of node i to node i + 1 (the last: none)
        if k > 1:
            O[:, :-1] = np.einsum("nkdkd->nkd", kept[:, :-1, :, 1:, :])
        first = 3 * self.chain_offsets[chosen][:, None] + np.arange(q)
        held = held[banded].reshape(-1, k, 3)
        D_free = np.where(held, 1.0, D)
        # a coupling that touches a prescribed DOF moves to the right-hand side
        O_free = np.where(held | np.roll(held, -1, axis=1), 0.0, O)
        d, l = np.empty_like(D), np.zeros_like(D)
        d[:, 0] = D_free[:, 0]
        for i in range(1, k):
            l[:, i] = O_free[:, i - 1] / d[:, i - 1]
            d[:, i] = D_free[:, i] - l[:, i] * O_free[:, i - 1]
        self.factor_l[first] = l.reshape(-1, q)
        self.factor_inverse_d[first] = (1.0 / d).reshape(-1, q)
        self.band_diagonal[first] = D.reshape(-1, q)
        self.band_coupling[first] = O.reshape(-1, q)

    def _chain_dof_table(self, chains: np.ndarray, k: int) -> np.ndarray:
        """The local DOFs (n, 3k) of ``chains`` (all of k nodes), slot-major."""
        nodes = self.chain_nodes[self.chain_offsets[chains][:, None] + np.arange(k)]
        return (3 * nodes[:, :, None] + np.arange(3)).reshape(len(chains), 3 * k)

    def partial(self, w: np.ndarray, out: np.ndarray) -> None:
        """This rank's share of the accelerations, before any exchange (``_partial_chains``):
        ``w`` (all local DOFs) holds this rank's share of the residual r = f_ext - f_int (N) at
        free DOFs and the given accelerations (mm/s^2) at the prescribed DOFs it owns; ``out``
        (all local DOFs) gets the share, to be summed on the owners (a reverse exchange) and
        passed to ``finish``. The scaled mass is linear: the shares of the ranks sum to the
        whole, so the residual needs no exchange of its own."""
        _partial_chains(
            self.chain_offsets,
            self.chain_nodes,
            self.matrix_offsets,
            self.matrix,
            self.inverse,
            self.held,
            self.banded,
            self.factor_l,
            self.factor_inverse_d,
            self.band_diagonal,
            self.band_coupling,
            self.prescribed,
            w,
            self.n_owned_dofs,
            out,
            self._dofs,
            self._scratch,
        )

    def finish(self, out: np.ndarray, acc: np.ndarray, reaction: np.ndarray) -> None:
        """From the shares ``out`` summed on their owners (owned entries): the accelerations of
        the free owned DOFs into ``acc`` (mm/s^2; its prescribed DOFs keep their given
        values), and the scaled mass's share (M_s a)_p - m_p a_p added to each reaction (N,
        one per prescribed owned DOF: the lumped m a - r before)."""
        _finish(out, self.prescribed, self.fixed, self.lumped, acc, reaction)

    def solve(self, acc: np.ndarray, reaction: np.ndarray) -> None:
        """Collective: ``acc`` (owned DOFs) holds r = f_ext - f_int (N) at free DOFs and the
        given accelerations at prescribed ones; overwritten with the accelerations of the scaled
        mass (mm/s^2), and the reactions (N, one per prescribed owned DOF: the lumped
        m a - r) get the scaled mass's share. ``partial``, summed by DOLFINx's reverse
        scatter, then ``finish``: the solver's step instead sums the shares in its forces'
        exchange."""
        w = self._w
        w.array[: self.n_owned_dofs] = acc
        w.array[self.n_owned_dofs :] = 0.0  # the owners hold the whole residual
        out = np.zeros_like(w.array)
        self.partial(w.array, out)
        w.array[:] = out
        w.scatter_reverse(la.InsertMode.add)
        self.finish(w.array, acc, reaction)

    def responses(self, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collective: the accelerations (n, owned DOFs; mm/s^2 per N) a force of each row of
        ``forces`` (n, owned DOFs, N) alone gives, with the prescribed DOFs held (a = 0 there),
        and the share (M_s a)_p each adds to the reactions (n, prescribed owned DOFs, N). For
        a force that is known only after the forces' exchange but always has one shape (the MMB
        lever's hinge: its size times a fixed vector), its accelerations are its size times
        these (the scaled mass is linear)."""
        n, k = len(forces), len(self.fixed)
        accelerations, reactions = np.zeros((n, self.n_owned_dofs)), np.zeros((n, k))
        for row in range(n):
            accelerations[row] = np.where(self.prescribed[: self.n_owned_dofs], 0.0, forces[row])
            self.solve(accelerations[row], reactions[row])
        return accelerations, reactions

    def multiply(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Collective: M_s x into ``out`` (owned DOFs; tonne x the unit of ``x``); ``x``: owned
        DOFs (the ghosts it needs are forward-scattered here). Returns ``out``."""
        w = self._w
        w.array[: self.n_owned_dofs] = x
        w.scatter_forward()
        _multiply_chains(
            self.chain_offsets,
            self.chain_nodes,
            self.matrix_offsets,
            self.matrix,
            w.array,
            self.n_owned_dofs,
            out,
            self._dofs,
        )
        return out

    def report(self, comm: MPI.Comm) -> dict:
        """Collective: what the scaling did, over all ranks, as ``summary.json`` gives it: the
        target step and the step the scaled elements allow (s), how many elements got mass,
        the largest factors."""
        lam = comm.allreduce(float(self.element_eigenvalues.max(initial=0.0)), op=MPI.MAX)
        return {
            "target_step_s": self.target_step,
            "element_step_s": 2.0 / np.sqrt(lam) if lam > 0 else np.inf,
            "elements": comm.allreduce(len(self.element_eigenvalues), op=MPI.SUM),
            "elements_scaled": comm.allreduce(
                int(np.count_nonzero((self.normal_scaling > 0) | (self.shear_scaling > 0))),
                op=MPI.SUM,
            ),
            "largest_normal_factor": comm.allreduce(
                float(self.normal_scaling.max(initial=0.0)), op=MPI.MAX
            ),
            "largest_shear_factor": comm.allreduce(
                float(self.shear_scaling.max(initial=0.0)), op=MPI.MAX
            ),
        }

    def stable_time_step(self) -> tuple[float, int]:
        """(2 / sqrt of the largest scaled element eigenvalue (s), its owned cell) on this
        rank; (inf, -1) without elements."""
        if len(self.element_eigenvalues) == 0:
            return np.inf, -1
        e = int(np.argmax(self.element_eigenvalues))
        return float(2.0 / np.sqrt(self.element_eigenvalues[e])), int(self.element_cell[e])


def adaptive_refused() -> InputError:
    """The one error for a scaled mass where cells refine (its columns would gain extra
    nodes, which it does not follow yet): raised before a run starts and, for a refinement
    asked for by other means, by ``Structure.refine``."""
    return InputError(
        "solver.mass_scaling",
        '"selective" is not yet available for adaptive models (their columns gain extra nodes '
        'when they refine): use it with ESL or layerwise models, or mass_scaling = "none"',
    )


def selective_mass(structure: Structure, target_step: float | None = None) -> SelectiveMass:
    """Collective: the selective scaled mass of ``structure``'s base nodes for the target step
    ``target_step`` (s; default: the in-plane step, see the module docstring). Raises
    InputError for a structure with extra nodes (an adaptive model: not yet) or a mesh whose
    elements do not stack into columns."""
    comm = structure.comm
    if structure.interfaces.refine or (
        comm.allreduce(structure.extra.index_map.size_local, op=MPI.SUM) > 0
    ):
        raise adaptive_refused()
    if structure.base.curved:
        raise InputError(
            "solver.mass_scaling",
            '"selective" is not yet available on curved shells (its element problems are '
            'taken in the global frame): use mass_scaling = "none" there',
        )
    nodes, cells, plies = structure.elements()
    nodes = nodes.astype(np.int64)
    X = structure.gather(nodes, "X")
    rules = structure.element_rules(plies)
    # the element problems of each distinct (shape, rule) once (a structured mesh has a few),
    # on the shape as its key gives it, so that the factors do not depend on the partition
    scale = comm.allreduce(float(np.abs(X - X[:, :1, :]).max(initial=0.0)), op=MPI.MAX)
    Xd, first, same = distinct_elements(X, rules, scale or 1.0)
    rules_d = rules[first]
    normals = edge_normals(Xd)
    m = structure.rule_table.lumped_masses(Xd, plies[first, 0], plies[first, 1])
    packed = structure.rule_table.packed
    blocks = [slice(i, i + ELEMENT_BLOCK) for i in range(0, len(first), ELEMENT_BLOCK)]
    stiffness = [element_stiffness(Xd[b], rules_d[b], packed) for b in blocks]
    in_plane = np.zeros(len(first))
    for K, b in zip(stiffness, blocks, strict=True):
        in_plane[b] = in_plane_eigenvalues(K, m[b])
    if target_step is None:
        largest = comm.allreduce(float(in_plane.max(initial=0.0)), op=MPI.MAX)
        # no longer than twice the cohesive springs' step: beyond that the solid elements'
        # share of the combined limit (``stable_step``) is below a fifth, and mass buys no step
        springs, _ = cohesive_time_step(structure)
        target_step = min(2.0 / np.sqrt(IN_PLANE_MARGIN * largest), 2.0 * springs)
        target = 4.0 / target_step**2
    else:
        target = 4.0 / target_step**2
    s_t, s_n, eigenvalues = (np.zeros(len(first)) for _ in range(3))
    for K, b in zip(stiffness, blocks, strict=True):
        s_t[b], s_n[b], eigenvalues[b] = scaling_factors(K, m[b], normals[b], target, in_plane[b])
    mu = reduced_edge_masses(m)
    edges = edge_blocks(normals, s_t[:, None] * mu, s_n[:, None] * mu)[same]
    s_t, s_n, eigenvalues = s_t[same], s_n[same], eigenvalues[same]
    chain_offsets, chain_nodes, matrix, lumped = _chain_matrices(
        structure, nodes[:, :4], nodes[:, 4:], edges
    )
    base = structure.base_block
    prescribed = la.vector(structure.mass_base.index_map, bs=3)
    prescribed.array[base.fixed] = 1.0
    prescribed.scatter_forward()
    adds_mass = comm.allreduce(bool(np.any(s_t > 0.0) or np.any(s_n > 0.0)), op=MPI.LOR)
    return SelectiveMass(
        adds_mass,
        structure.mass_base.index_map,
        chain_offsets,
        chain_nodes,
        matrix,
        lumped,
        prescribed.array > 0.5,
        base.fixed,
        float(target_step),
        eigenvalues,
        cells,
        (s_t, s_n),
    )


def distinct_elements(
    X: np.ndarray, rules: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct element shapes (vertices relative to the first one, rounded to 1e-10 of
    ``scale`` mm: (m, 8, 3)), the first element of each, and the distinct one of every element;
    shapes count as the same only with the same ``rules``."""
    relative = (X - X[:, :1, :]).reshape(len(X), -1)
    keys = np.column_stack([rules, np.round(relative / scale * 1e10)])
    unique, first, same = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    shapes = (unique[:, 1:] * (scale * 1e-10)).reshape(-1, 8, 3)
    return shapes, first, same.ravel()


def _chain_matrices(
    structure: Structure, bottom: np.ndarray, top: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The chains of base nodes joined by the edges (``bottom`` -> ``top``, (n, 4) local nodes,
    edge blocks ``edges`` (n, 4, 3, 3)), every local node in one, as CSR (offsets, local nodes
    bottom to top); their 3k x 3k matrices packed row by row: the lumped masses on the
    diagonal, each edge's block (summed over the ranks) as a spring between its two nodes; and
    the lumped mass of each local DOF."""
    index_map = structure.mass_base.index_map
    n_local = index_map.size_local + index_map.num_ghosts
    bottom, top, edges = bottom.ravel(), top.ravel(), edges.reshape(-1, 3, 3)
    above = np.full(n_local, -1, dtype=np.int64)
    above[bottom] = top
    if np.any(above[bottom] != top):
        i = int(np.flatnonzero(above[bottom] != top)[0])
        raise InputError(
            "mesh",
            f"selective mass scaling: the node at {structure.X_base[bottom[i]].round(6).tolist()}"
            " mm is the bottom of two through-thickness edges; the elements must stack in "
            "columns (vertex a + 4 above vertex a)",
        )
    below = np.full(n_local, -1, dtype=np.int64)
    below[top] = bottom
    if np.any(below[top] != bottom):
        i = int(np.flatnonzero(below[top] != bottom)[0])
        raise InputError(
            "mesh",
            f"selective mass scaling: the node at {structure.X_base[top[i]].round(6).tolist()}"
            " mm is the top of two through-thickness edges; the elements must stack in "
            "columns (vertex a + 4 above vertex a)",
        )
    # each node's edge block to the node above and whether an edge starts or ends there,
    # summed over the ranks (an edge's elements may lie on several)
    edge = la.vector(index_map, bs=8)
    values = edge.array.reshape(-1, 8)
    for column, (i, j) in enumerate(SYMMETRIC):
        np.add.at(values[:, column], bottom, edges[:, i, j])
    np.add.at(values[:, 6], bottom, 1.0)
    np.add.at(values[:, 7], top, 1.0)
    edge.scatter_reverse(la.InsertMode.add)
    edge.scatter_forward()
    has_above, has_below = values[:, 6] > 0, values[:, 7] > 0
    mass = la.vector(index_map, bs=3)
    mass.array[:] = structure.mass_base.array
    mass.scatter_forward()
    node_mass = mass.array[::3].copy()

    # walk up from every chain's bottom node, one level at a time
    levels = [np.flatnonzero(below < 0)]
    while True:
        last = levels[-1]
        up = np.where(last >= 0, above[np.maximum(last, 0)], -1)
        if not np.any(up >= 0):
            break
        levels.append(up)
    # every chain of local nodes: a rank solves its share of each chain it holds a force on,
    # ghosts included (``SelectiveMass.partial``)
    table = np.stack(levels, axis=1)  # (chains, levels), -1 past a chain's top
    sizes = (table >= 0).sum(axis=1)
    chain_nodes = table[table >= 0]  # row by row: each chain bottom to top
    broken = (has_above & (above < 0)) | (has_below & (below < 0))
    if np.any(broken[chain_nodes]):
        where = structure.X_base[chain_nodes[np.argmax(broken[chain_nodes])]].round(6).tolist()
        raise InputError(
            "mesh",
            f"selective mass scaling: the column through {where} mm is split between MPI "
            "ranks (its cells are not all on one rank); partition the mesh by columns or run "
            "on one rank",
        )
    chain_offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    q = 3 * sizes
    matrix_offsets = np.concatenate([[0], np.cumsum(q**2)]).astype(np.int64)
    matrix = np.zeros(int(matrix_offsets[-1]))
    chain = np.repeat(np.arange(len(sizes)), sizes)
    slot = np.arange(len(chain_nodes)) - chain_offsets[chain]
    qq, first = q[chain], matrix_offsets[chain]  # per chain node
    for d in range(3):
        row = 3 * slot + d
        matrix[first + row * qq + row] = node_mass[chain_nodes]
    inner = np.flatnonzero(slot < sizes[chain] - 1)  # an edge from this slot to the next
    for column, (i, j) in enumerate(SYMMETRIC):
        b = values[chain_nodes[inner], column]
        low, high = 3 * slot[inner], 3 * slot[inner] + 3
        pairs = ((i, j), (j, i)) if i != j else ((i, i),)
        for ri, ci in pairs:
            for r, c, sign in ((low, low, 1), (high, high, 1), (low, high, -1), (high, low, -1)):
                matrix[first[inner] + (r + ri) * qq[inner] + c + ci] += sign * b
    return chain_offsets, chain_nodes.astype(np.int64), matrix, np.repeat(node_mass, 3)
