"""Numba kernels of the layered 8-node solid-shell (sub)element: internal force and lumped mass.

Units: N, mm, s, tonne. Coordinates and displacements in mm, stiffness in MPa, density in
tonne/mm^3, forces in N, strain energy in mJ (N mm), masses in tonne.

What is computed. One (sub)element is an 8-node hexahedron spanning a contiguous range of plies
of the laminate. An unrefined (ESL) element spans all of them; after refinement at some ply
interfaces each subelement spans the plies between two active interfaces (paper, Figure 2).
Integration points never move: a ply keeps the points ``solid_shell.ply_rules`` gives it inside
its own zeta range, expressed in the reference thickness [0, 1] of the (sub)element that holds it;
or, pre-integrated (``solid_shell.thickness_rule``), the (sub)element has three points whose
stiffnesses carry its plies' moments, and a point belongs to no ply.
The force here must be, to round-off, the derivative of ``solid_shell.strain_energy_form`` for a
hexahedron carrying those plies; ``tests/test_subelement.py`` checks that against DOLFINx.

Conventions (the same as ``solid_shell`` and ``timestep.reference_gradients``):

- reference cell [0, 1]^3; vertex k sits at (k & 1, (k >> 1) & 1, (k >> 2) & 1) (DOLFINx
  order); zeta, the third reference coordinate, runs through the laminate thickness;
- ``X``, ``u`` are (8, 3) arrays of vertex coordinates / displacements in that vertex order;
- small strain, Voigt order (xx, yy, zz, yz, xz, xy) with engineering shears; or, with
  ``finite=True``, the Green-Lagrange strain E = 1/2 (H + H^T + H^T H), H = Grad u (the same
  Voigt order, 2 E_ij as the shears) and the second Piola-Kirchhoff stress S = C E (total
  Lagrangian; ``solid_shell`` module docstring), e below standing for E and sigma for S;
- strain energy of the selective (ANS-equivalent) rule, per integration point of weight w:

    term 0 "normal"       2x2 in-plane   1/2 e_N . C[N, N] e_N, N = (xx, yy, zz, xy) = (0, 1, 2, 5)
    term 1 "shear_xz"     1x2            1/2 C[4, 4] g_xz^2
    term 2 "shear_yz"     2x1            1/2 C[3, 3] g_yz^2
    term 3 "shear_cross"  1x1            C[3, 4] g_xz g_yz

  times w |det J|, J = dx/d(xi, eta, zeta) (abs, as UFL does); the force is the gradient of the
  total with respect to the nodal displacements. On a cell whose vertical edges are not
  parallel, e carries the thickness strain sampled on those edges (``assumed_strain``).

How the kernel is organised (for speed). The trilinear map is written in monomials,
x = sum_m b_m xi^(m & 1) eta^((m >> 1) & 1) zeta^((m >> 2) & 1) (b = Moebius transform of the
vertex values, 3 butterfly stages), and likewise u. At fixed (xi, eta), J = dx/d(xi, eta, zeta)
and the reference displacement gradient are then affine in zeta. Every point of the rule sits on
one of a few in-plane positions (the 3 x 3 grid of the selective rule), and each position
carries one energy term. The packed rule lists the points line by line, so per element the
kernel takes one line at a time: it forms intercept and slope of J and of du/d(xi, eta, zeta)
on it, then runs one branch-free loop over the line's points (three, or one or two per ply),
which the compiler vectorises: evaluate both maps with one multiply-add per entry, invert J,
accumulate P = w |det J| sigma J^-T into two moments (sum P, sum zeta P). The moments become
derivatives with respect to the monomial coefficients, and the transposed butterfly takes them
back to the 8 vertices at the end. With finite kinematics the per-point P is w |det J| F S J^-T
(first Piola-Kirchhoff stress times the reference gradient map: the derivative of 1/2 S : E),
F = I + H; the rest is unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numba import njit

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element.assumed_strain import (
    add_correction_forces,
    cell_strain_coefficients,
    corrected_strain,
    directors_bend,
    edge_sampled_strain,
    stress_on_director,
    work_weights,
)
from fenics_adaptive.materials.ply_damage import (
    P_C22,
    RESIDUAL,
    S_D,
    S_DF,
    S_DISSIPATED,
    S_ERODED,
    S_FIBRE_DISSIPATED,
    S_YF_LAST,
    matrix_release_rates,
    ply_damage_update,
)
from fenics_adaptive.settings.materials import F_GFT

# Term codes of the packed rule, in the order of solid_shell.TERMS.
TERM_NORMAL, TERM_SHEAR_XZ, TERM_SHEAR_YZ, TERM_SHEAR_CROSS = range(4)
TERM_CODES = {term: code for code, term in enumerate(solid_shell.TERMS)}
assert TERM_CODES == {
    "normal": TERM_NORMAL,
    "shear_xz": TERM_SHEAR_XZ,
    "shear_yz": TERM_SHEAR_YZ,
    "shear_cross": TERM_SHEAR_CROSS,
}

# Reference coordinates of the 8 vertices (DOLFINx order).
CORNERS = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=np.float64)


def _in_plane_positions() -> np.ndarray:
    """The distinct in-plane (xi, eta) positions used by ``solid_shell.ply_rules`` (independent
    of the ply's zeta range and of the points per ply), in order of first appearance."""
    positions: list[tuple[float, float]] = []
    for points, _ in solid_shell.ply_rules(0.0, 1.0, 1).values():
        for xi, eta, _zeta in points:
            if (xi, eta) not in positions:
                positions.append((float(xi), float(eta)))
    return np.array(positions, dtype=np.float64)


IN_PLANE_POSITIONS = _in_plane_positions()  # (n_pos, 2); 9 for the selective rule


def _ply_bounds(ply_zeta: np.ndarray) -> np.ndarray:
    """(n_plies, 2) ply bounds from either (n_plies, 2) bounds or (n_plies + 1,) boundaries;
    checked to tile the reference thickness [0, 1] bottom to top."""
    z = np.asarray(ply_zeta, dtype=np.float64)
    if z.ndim == 1:
        if z.size < 2:
            raise ValueError("ply_zeta: need at least two ply boundaries")
        z = np.column_stack([z[:-1], z[1:]])
    if z.ndim != 2 or z.shape[1] != 2 or z.shape[0] == 0:
        raise ValueError(f"ply_zeta: expected shape (n_plies, 2), got {z.shape}")
    tol = 1e-12
    if not np.all(np.isfinite(z)) or np.any(z[:, 1] <= z[:, 0]):
        raise ValueError("ply_zeta: every ply needs zeta_lo < zeta_hi")
    if (
        abs(z[0, 0]) > tol
        or abs(z[-1, 1] - 1.0) > tol
        or np.any(np.abs(z[1:, 0] - z[:-1, 1]) > tol)
    ):
        raise ValueError(
            "ply_zeta: the plies must tile this (sub)element's reference thickness [0, 1] "
            "bottom to top (renormalise a subelement's ply bounds to its own thickness)"
        )
    return z


def sublaminate_ply_zeta(ply_fractions: np.ndarray, first: int, stop: int) -> np.ndarray:
    """(stop - first, 2) bounds of plies ``first:stop`` (0-based, bottom to top) inside the
    reference thickness [0, 1] of the subelement that spans exactly those plies, from the
    laminate's ``ply_fractions`` (n_plies + 1,). The subelement's bottom vertices sit at the
    fraction f_first, its top ones at f_stop of the parent element's vertical edges."""
    f = np.asarray(ply_fractions, dtype=np.float64)
    if not 0 <= first < stop <= len(f) - 1:
        raise ValueError(f"plies {first}:{stop} are not a range of the {len(f) - 1} plies")
    z = (f[first : stop + 1] - f[first]) / (f[stop] - f[first])
    z[-1] = 1.0
    return np.column_stack([z[:-1], z[1:]])


class PackedRule(NamedTuple):
    """Integration rule of the internal force of one (sub)element, as flat arrays; the fields are
    the kernel's arguments in order: ``solid_shell_force(X, u, *rule, f_out)``.

    The points are ordered by vertical line (in-plane position), and bottom to top along each
    line; every line carries every ply, so the first point is on the lowest ply and the last on
    the highest. The kernels are correct in any order but fast only in this one (a line's
    points are one vectorised loop)."""

    zeta: np.ndarray  # (n,) reference thickness coordinate of the points on [0, 1]
    weights: np.ndarray  # (n,) reference weights; those of each term sum to 1
    terms: np.ndarray  # (n,) int64 term code: 0 normal, 1 shear_xz, 2 shear_yz, 3 shear_cross
    ply_of_point: np.ndarray  # (n,) int64 index into ``stiffness``
    position_of_point: np.ndarray  # (n,) int64 index into ``positions``
    positions: np.ndarray  # (n_pos, 2) in-plane (xi, eta) of the points' vertical lines
    stiffness: np.ndarray  # (n_plies, 6, 6) shell-frame stiffness of each ply, MPa
    # (n,) shape of the enhanced thickness strain at each point: zeta - 1/2 on the "normal"
    # points of a rule with it (``solid_shell.enhanced_mode``), 0 elsewhere and without it
    enhanced_mode: np.ndarray

    def coordinates(self) -> np.ndarray:
        """(n, 3) reference coordinates (xi, eta, zeta) of the points on [0, 1]^3."""
        return np.column_stack([self.positions[self.position_of_point], self.zeta])


def pack_rule(
    ply_zeta: np.ndarray,
    ply_stiffness: np.ndarray,
    points_per_ply: int,
    shear_factors=None,
    enhanced: bool = False,
    preintegrate: bool = False,
) -> PackedRule:
    """Pack the selective solid-shell rule of a (sub)element.

    ``ply_zeta``: the bounds of its plies inside its OWN reference thickness [0, 1], bottom to
    top, as (n_plies, 2) or as (n_plies + 1,) boundaries (for an unrefined element:
    ``laminate.ply_fractions``; for a subelement spanning plies i..j of the laminate:
    (f_k - f_i) / (f_{j+1} - f_i)). ``ply_stiffness``: (n_plies, 6, 6) shell-frame stiffness
    (MPa, Voigt xx, yy, zz, yz, xz, xy, engineering shears), symmetric and monoclinic (no
    normal/transverse-shear coupling: the selective rule drops it). ``points_per_ply``: Gauss
    points through the thickness of each ply, ``preintegrate``: the laminate's three
    pre-integrated points instead where ``solid_shell.thickness_rule`` takes them (then
    ``stiffness`` holds their three stiffnesses, and ``ply_of_point`` indexes those, not plies).
    Per ply, the points are those of ``solid_shell.ply_rules``, ply by ply, and ply k uses
    ``stiffness[k]``. ``shear_factors``: each ply's transverse shear factors (m_xz, m_yz;
    ``materials.laminate.ply_shear_factors``; ``solid_shell.per_ply_shear_factors``), on the
    weights of its points' shear terms (``solid_shell.shear_weights``; pre-integrated, their
    span mean). ``enhanced``: the enhanced assumed thickness strain
    (``solid_shell`` module docstring), condensed by the kernels line by line."""
    bounds = _ply_bounds(ply_zeta)
    C = np.ascontiguousarray(ply_stiffness, dtype=np.float64)
    if C.shape != (len(bounds), 6, 6):
        raise ValueError(f"ply_stiffness: expected shape ({len(bounds)}, 6, 6), got {C.shape}")
    for k in range(len(bounds)):
        if np.abs(C[k] - C[k].T).max() > 1e-12 * np.abs(C[k]).max():
            raise ValueError(f"ply_stiffness[{k}] is not symmetric")
        solid_shell.check_monoclinic(C[k])
    if int(points_per_ply) != points_per_ply or points_per_ply < 1:
        raise ValueError(f"points_per_ply must be an integer >= 1 (got {points_per_ply})")
    position_index = {(xi, eta): q for q, (xi, eta) in enumerate(IN_PLANE_POSITIONS)}
    through = solid_shell.thickness_rule(bounds, C, int(points_per_ply), preintegrate)
    points, weights, terms, plies = [], [], [], []
    m = solid_shell.per_ply_shear_factors(shear_factors, len(bounds))
    if through.preintegrated:  # (a point belongs to no ply)
        factor = np.tile(solid_shell.span_shear_weights(m, bounds, ply_stiffness), (3, 1))
    else:
        factor = solid_shell.shear_weights(m)
    for term, (p, w) in solid_shell.term_rules(through.zeta, through.weights).items():
        # term_rules lists each through-thickness point's in-plane points together
        of_point = np.repeat(through.stiffness_of_point, len(w) // len(through.zeta))
        points.append(p)
        weights.append(factor[of_point, TERM_CODES[term]] * w)
        terms.append(np.full(len(w), TERM_CODES[term], dtype=np.int64))
        plies.append(of_point)
    C = np.ascontiguousarray(through.stiffness)
    points = np.vstack(points)
    position_of_point = np.array(
        [position_index[(xi, eta)] for xi, eta in points[:, :2]], dtype=np.int64
    )
    # line by line; the stable sort keeps each line bottom to top
    order = np.argsort(position_of_point, kind="stable")
    terms = np.concatenate(terms)[order]
    zeta = np.ascontiguousarray(points[order, 2], dtype=np.float64)
    mode = solid_shell.enhanced_mode(zeta) if enhanced else np.zeros_like(zeta)
    return PackedRule(
        zeta=zeta,
        weights=np.concatenate(weights).astype(np.float64)[order],
        terms=terms,
        ply_of_point=np.concatenate(plies)[order],
        position_of_point=position_of_point[order],
        positions=IN_PLANE_POSITIONS.copy(),
        stiffness=C,
        enhanced_mode=np.where(terms == TERM_NORMAL, mode, 0.0),
    )


class PackedRules(NamedTuple):
    """Several packed rules concatenated, CSR style: the points of rule r are
    ``rule_offsets[r]:rule_offsets[r + 1]``; ``ply_of_point`` indexes the concatenated
    ``stiffness``. The fields are the batched kernel's arguments in order:
    ``solid_shell_forces(X_all, u_all, rule_of_element, *rules, f_all, finite)``."""

    rule_offsets: np.ndarray  # (n_rules + 1,) int64
    zeta: np.ndarray
    weights: np.ndarray
    terms: np.ndarray
    ply_of_point: np.ndarray
    position_of_point: np.ndarray
    positions: np.ndarray
    stiffness: np.ndarray
    enhanced_mode: np.ndarray


def concatenate_rules(rules: Sequence[PackedRule]) -> PackedRules:
    """Concatenate packed rules (e.g. one per layup or one per (sub)element) for
    ``solid_shell_forces``."""
    if len(rules) == 0:
        raise ValueError("concatenate_rules: no rules")
    for rule in rules:
        if not np.array_equal(rule.positions, rules[0].positions):
            raise ValueError("concatenate_rules: the rules use different in-plane positions")
    counts = [len(rule.weights) for rule in rules]
    ply_offsets = np.cumsum([0] + [len(rule.stiffness) for rule in rules])
    return PackedRules(
        rule_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        zeta=np.concatenate([r.zeta for r in rules]),
        weights=np.concatenate([r.weights for r in rules]),
        terms=np.concatenate([r.terms for r in rules]),
        ply_of_point=np.concatenate(
            [r.ply_of_point + ply_offsets[i] for i, r in enumerate(rules)]
        ).astype(np.int64),
        position_of_point=np.concatenate([r.position_of_point for r in rules]),
        positions=rules[0].positions.copy(),
        stiffness=np.ascontiguousarray(np.concatenate([r.stiffness for r in rules])),
        enhanced_mode=np.concatenate([r.enhanced_mode for r in rules]),
    )


class PackedMassRule(NamedTuple):
    """Lumped-mass rule of one (sub)element; the fields are the kernel's arguments in order:
    ``solid_shell_lumped_mass(X, *mass_rule, m_out)``."""

    points: np.ndarray  # (n, 3) reference points, 2x2x2 Gauss per ply (solid_shell.mass_rule)
    weights: np.ndarray  # (n,) reference weights, summing to 1
    ply_of_point: np.ndarray  # (n,) int64 index into ``density``
    density: np.ndarray  # (n_plies,) tonne/mm^3


def pack_mass_rule(ply_zeta: np.ndarray, ply_density: np.ndarray) -> PackedMassRule:
    """Pack ``solid_shell.mass_rule`` for every ply of a (sub)element (``ply_zeta`` as in
    ``pack_rule``), with the ply densities (tonne/mm^3)."""
    bounds = _ply_bounds(ply_zeta)
    rho = np.ascontiguousarray(ply_density, dtype=np.float64)
    if rho.shape != (len(bounds),) or not np.all(np.isfinite(rho)) or np.any(rho < 0.0):
        raise ValueError(f"ply_density: expected {len(bounds)} densities >= 0, got {rho!r}")
    points, weights, plies = [], [], []
    for k, (lo, hi) in enumerate(bounds):
        p, w = solid_shell.mass_rule(lo, hi)
        points.append(p)
        weights.append(w)
        plies.append(np.full(len(w), k, dtype=np.int64))
    return PackedMassRule(
        points=np.ascontiguousarray(np.vstack(points), dtype=np.float64),
        weights=np.concatenate(weights).astype(np.float64),
        ply_of_point=np.concatenate(plies),
        density=rho,
    )


# ---------------------------------------------------------------------------------------------
# kernels


@njit(cache=True)
def gather_nodes(nodes, n_base, base, extra, out):
    """out (8, 3) = values of 8 nodes given in combined local indices: i < n_base is base node
    i (``base`` (n, 3)), else extra node i - n_base (``extra``)."""
    for a in range(8):
        node = nodes[a]
        for i in range(3):
            out[a, i] = base[node, i] if node < n_base else extra[node - n_base, i]


@njit(cache=True)
def scatter_add_nodes(nodes, n_base, values, sign, base, extra):
    """Add sign * values (8, 3) onto 8 nodes in combined local indices (see gather_nodes)."""
    for a in range(8):
        node = nodes[a]
        if node < n_base:
            for i in range(3):
                base[node, i] += sign * values[a, i]
        else:
            for i in range(3):
                extra[node - n_base, i] += sign * values[a, i]


@njit(cache=True)
def _monomials(values, out):
    """out (8, 3) = coefficients b_m of the trilinear interpolant of ``values`` (8, 3) in the
    monomials xi^(m & 1) eta^((m >> 1) & 1) zeta^((m >> 2) & 1): the Moebius transform
    b_m = sum over vertices a within m of (-1)^|m - a| values_a, in three butterfly stages."""
    for a in range(8):
        for i in range(3):
            out[a, i] = values[a, i]
    for d in range(3):
        bit = 1 << d
        for m in range(8):
            if m & bit:
                for i in range(3):
                    out[m, i] -= out[m ^ bit, i]


# Compiler options of ``element_force_kernel`` and of every kernel that calls it. The point
# kernels are inlined at numba's IR level, where the caller's flags are the ones that apply.
# Fast-math subset without "nnan"/"ninf": a degenerate element still gives inf/nan, not garbage.
KERNEL_OPTIONS = {"error_model": "numpy", "fastmath": {"contract", "reassoc", "nsz", "arcp"}}
# Higham's polar iteration, scaled by |det R|^(-1/3): about eight steps from any conditioning;
# an element whose fit does not converge, or turns itself inside out, gets a NaN frame (the
# not-finite guard then stops the run) rather than a reflection or a wrong rotation
POLAR_ITERATIONS = 30
POLAR_TOLERANCE = 1.0e-14


@njit(inline="always")
def _fill_line(bx, bu, xi, eta, line):
    """On the vertical line (xi, eta): J = line[0] + zeta line[1] (J[i, r] = dx_i/dX_r) and
    G = line[2] + zeta line[3] (G[i, r] = du_i/dX_r), from the monomial coefficients ``bx`` and
    ``bu`` (8, 3) of x and u; column r = 2 (d/dzeta) has no slope."""
    for s in range(2):
        b = bx if s == 0 else bu
        for i in range(3):
            line[2 * s, i, 0] = b[1, i] + eta * b[3, i]
            line[2 * s + 1, i, 0] = b[5, i] + eta * b[7, i]
            line[2 * s, i, 1] = b[2, i] + xi * b[3, i]
            line[2 * s + 1, i, 1] = b[6, i] + xi * b[7, i]
            line[2 * s, i, 2] = b[4, i] + xi * b[5, i] + eta * (b[6, i] + xi * b[7, i])
            line[2 * s + 1, i, 2] = 0.0


@njit(inline="always")
def _inverse3(J):
    """(det J, K = J^-1) of a row-major 3 x 3 9-tuple J, K as a row-major 9-tuple (the
    cofactors over the determinant; one division)."""
    J00, J01, J02, J10, J11, J12, J20, J21, J22 = J
    c00 = J11 * J22 - J12 * J21
    c01 = J12 * J20 - J10 * J22
    c02 = J10 * J21 - J11 * J20
    det = J00 * c00 + J01 * c01 + J02 * c02
    inv_det = 1.0 / det
    K = (
        c00 * inv_det,
        (J02 * J21 - J01 * J22) * inv_det,
        (J01 * J12 - J02 * J11) * inv_det,
        c01 * inv_det,
        (J00 * J22 - J02 * J20) * inv_det,
        (J02 * J10 - J00 * J12) * inv_det,
        c02 * inv_det,
        (J01 * J20 - J00 * J21) * inv_det,
        (J00 * J11 - J01 * J10) * inv_det,
    )
    return det, K


@njit(inline="always")
def _line_matrix(line, s, z):
    """Matrix s (0: J, 2: G) of a vertical line (``_fill_line``) at height z, as a row-major
    9-tuple: line[s] + z line[s + 1], whose third column has no slope."""
    return (
        line[s, 0, 0] + z * line[s + 1, 0, 0],
        line[s, 0, 1] + z * line[s + 1, 0, 1],
        line[s, 0, 2],
        line[s, 1, 0] + z * line[s + 1, 1, 0],
        line[s, 1, 1] + z * line[s + 1, 1, 1],
        line[s, 1, 2],
        line[s, 2, 0] + z * line[s + 1, 2, 0],
        line[s, 2, 1] + z * line[s + 1, 2, 1],
        line[s, 2, 2],
    )


@njit(inline="always")
def _inverse_jacobian(line, z):
    """(det J, K) at height z of a vertical line (``_fill_line``); K = J^-1 (K[r, j] =
    dX_r/dx_j) as a row-major 9-tuple."""
    return _inverse3(_line_matrix(line, 0, z))


@njit(inline="always")
def _displacement_gradient(line, z):
    """G[i, r] = du_i/dX_r at height z of a vertical line, as a row-major 9-tuple."""
    return _line_matrix(line, 2, z)


@njit(inline="always")
def _matmul3(A, B):
    """A B of two row-major 3 x 3 9-tuples."""
    return (
        A[0] * B[0] + A[1] * B[3] + A[2] * B[6],
        A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
        A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
        A[3] * B[0] + A[4] * B[3] + A[5] * B[6],
        A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
        A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
        A[6] * B[0] + A[7] * B[3] + A[8] * B[6],
        A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
        A[6] * B[2] + A[7] * B[5] + A[8] * B[8],
    )


@njit(inline="always")
def _strain(H, finite):
    """(exx, eyy, ezz, gyz, gxz, gxy) of the displacement gradient H (row-major 9-tuple): the
    small strain, or with ``finite`` the Green-Lagrange strain (engineering shears 2 E_ij)."""
    exx = H[0]
    eyy = H[4]
    ezz = H[8]
    gyz = H[5] + H[7]
    gxz = H[2] + H[6]
    gxy = H[1] + H[3]
    if finite:
        exx += 0.5 * (H[0] * H[0] + H[3] * H[3] + H[6] * H[6])
        eyy += 0.5 * (H[1] * H[1] + H[4] * H[4] + H[7] * H[7])
        ezz += 0.5 * (H[2] * H[2] + H[5] * H[5] + H[8] * H[8])
        gyz += H[1] * H[2] + H[4] * H[5] + H[7] * H[8]
        gxz += H[0] * H[2] + H[3] * H[5] + H[6] * H[8]
        gxy += H[0] * H[1] + H[3] * H[4] + H[6] * H[7]
    return exx, eyy, ezz, gyz, gxz, gxy


@njit(inline="always")
def _point_kinematics(line, z, weight, maps, row, finite):
    """(w |det J|, K = J^-1, H, strain) of a point (``_strain`` order): computed from its
    line, or, when ``maps`` is given (small strain only), read from column ``row`` where the
    damaged kernel's strain pass left them (H is then not needed and returned as zeros)."""
    if maps is None:
        det, K = _inverse_jacobian(line, z)
        H = _matmul3(_displacement_gradient(line, z), K)
        return weight * abs(det), K, H, _strain(H, finite)
    K = (
        maps[1, row],
        maps[2, row],
        maps[3, row],
        maps[4, row],
        maps[5, row],
        maps[6, row],
        maps[7, row],
        maps[8, row],
        maps[9, row],
    )
    strain = (
        maps[10, row],
        maps[11, row],
        maps[12, row],
        maps[13, row],
        maps[14, row],
        maps[15, row],
    )
    return maps[0, row], K, (0.0,) * 9, strain


@njit(inline="always")
def _normal_stress_map(sxx, syy, szz, sxy, K):
    """P[i, r] = sum_j sigma_ij K[r, j] of a stress without transverse shear (the products
    with its zeros are left out: without "nnan" the compiler may not drop them)."""
    return (
        sxx * K[0] + sxy * K[1],
        sxx * K[3] + sxy * K[4],
        sxx * K[6] + sxy * K[7],
        sxy * K[0] + syy * K[1],
        sxy * K[3] + syy * K[4],
        sxy * K[6] + syy * K[7],
        szz * K[2],
        szz * K[5],
        szz * K[8],
    )


@njit(inline="always")
def _shear_stress_map(syz, sxz, K):
    """P[i, r] = sum_j sigma_ij K[r, j] of a pure transverse shear stress."""
    return (
        sxz * K[2],
        sxz * K[5],
        sxz * K[8],
        syz * K[2],
        syz * K[5],
        syz * K[8],
        sxz * K[0] + syz * K[1],
        sxz * K[3] + syz * K[4],
        sxz * K[6] + syz * K[7],
    )


@njit(inline="always")
def _first_piola(P, H, finite):
    """With ``finite``: F P = P + H P (P was S J^-T, the first Piola-Kirchhoff stress mapped to
    the reference gradient); else P."""
    if finite:
        HP = _matmul3(H, P)
        return (
            P[0] + HP[0],
            P[1] + HP[1],
            P[2] + HP[2],
            P[3] + HP[3],
            P[4] + HP[4],
            P[5] + HP[5],
            P[6] + HP[6],
            P[7] + HP[7],
            P[8] + HP[8],
        )
    return P


@njit(inline="always")
def _line_end(position_of_point, p, stop):
    """End of the run of points from p on that share p's vertical line."""
    end = p + 1
    while end < stop and position_of_point[end] == position_of_point[p]:
        end += 1
    return end


@njit(inline="always")
def _add_point_moments(m, n, P, z):
    """(m + P, n + z P[:, :2]): a point's P (row-major 9-tuple) added to its line's moments
    m = sum P and n = sum zeta P (the 6 entries of columns 0 and 1, row by row)."""
    return (
        m[0] + P[0],
        m[1] + P[1],
        m[2] + P[2],
        m[3] + P[3],
        m[4] + P[4],
        m[5] + P[5],
        m[6] + P[6],
        m[7] + P[7],
        m[8] + P[8],
    ), (
        n[0] + z * P[0],
        n[1] + z * P[1],
        n[2] + z * P[3],
        n[3] + z * P[4],
        n[4] + z * P[6],
        n[5] + z * P[7],
    )


@njit(inline="always")
def _add_scaled_moments(m, n, a, mc, nc):
    """(m + a mc, n + a nc) of line moments (``_add_point_moments``)."""
    return (
        m[0] + a * mc[0],
        m[1] + a * mc[1],
        m[2] + a * mc[2],
        m[3] + a * mc[3],
        m[4] + a * mc[4],
        m[5] + a * mc[5],
        m[6] + a * mc[6],
        m[7] + a * mc[7],
        m[8] + a * mc[8],
    ), (
        n[0] + a * nc[0],
        n[1] + a * nc[1],
        n[2] + a * nc[2],
        n[3] + a * nc[3],
        n[4] + a * nc[4],
        n[5] + a * nc[5],
    )


@njit(inline="always")
def _add_line_moments(f_out, xi, eta, m, n):
    """Add one line's moments m = sum P (9-tuple) and n = sum zeta P (the 6 entries of columns
    0 and 1) to the derivatives F_m (8, 3) with respect to the monomial coefficients of u:
    F_m = sum_points dphi_m/dX_r P[:, r], phi_m = xi^(m & 1) eta^((m >> 1) & 1) zeta^(m >> 2)."""
    for i in range(3):
        m0x = m[3 * i]
        m0y = m[3 * i + 1]
        m0z = m[3 * i + 2]
        m1x = n[2 * i]
        m1y = n[2 * i + 1]
        f_out[1, i] += m0x
        f_out[2, i] += m0y
        f_out[3, i] += eta * m0x + xi * m0y
        f_out[4, i] += m0z
        f_out[5, i] += m1x + xi * m0z
        f_out[6, i] += m1y + eta * m0z
        f_out[7, i] += eta * m1x + xi * m1y + xi * eta * m0z


# Compiled once, as a function of its own, with ``finite`` an argument: inlined into every
# kernel (through a wrapper that passed ``finite`` as a constant), numba kept both kinematics of
# the body, and the damaged kernel (with ``_condense_with_damage`` inlined twice besides) became
# one function that LLVM took 148 s to compile on 2 vCPUs (the ply-damage warm-up 206 s);
# split, 50 s (87 s). The elastic kernel's time per step did not move; the damaged one's best
# of 25 moved by 2-4 %, within the machine's spread (2026-12-08, AMD EPYC).
@njit(**KERNEL_OPTIONS)
def element_force_kernel(
    X,
    u,
    start,
    stop,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    work,
    line,
    f_out,
    opening,
    opening_scale,
    maps,
    finite,
):
    """Force of one element from points start:stop of the packed arrays into f_out (8, 3),
    overwritten; returns the strain energy. Work arrays: ``work`` (2, 8, 3), ``line``
    (4, 3, 3). ``finite``: Green-Lagrange strain and second Piola-Kirchhoff stress instead of
    small strain (not combined with matrix cracks: the caller, the damaged kernel, is
    small-strain, in a co-rotated frame under finite kinematics).

    The points come in runs sharing a vertical line, and with it the energy term (the rule's
    order, ``pack_rule``); each run is one loop without branches on the point, which the
    compiler vectorises over the plies.

    Matrix cracks (damaged kernel only; ``opening_scale`` None otherwise): where
    ``opening_scale[k]`` > 0, ply k's ``stiffness`` is its closed-crack stiffness and, point by
    point, the crack opens where the effective transverse stress s = opening[k] . (exx, eyy,
    ezz, 0, 0, gxy) is positive: the stress loses opening_scale[k] s opening[k] and the energy
    1/2 opening_scale[k] s^2. Decided per point, this keeps the material elastic between damage
    increments (a per-ply switch on the mean stress pumps energy into a ringing cracked ply)."""
    bx = work[0]
    bu = work[1]
    _monomials(X, bx)
    _monomials(u, bu)
    for a in range(8):
        for i in range(3):
            f_out[a, i] = 0.0
    energy = 0.0
    # the edge-sampled thickness strain of a cell with bent directors (``assumed_strain``):
    # its strain gains dE k k (already in ``maps`` when given), its stress does work T dE
    bent = directors_bend(bx)
    s55 = s57 = s77 = s66 = s67 = 0.0
    if bent:
        s55, s57, s77, s66, s67 = cell_strain_coefficients(bx, bu, finite)
    W = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # the cell's work weights
    dE = 0.0
    p = start
    while p < stop:
        end = _line_end(position_of_point, p, stop)
        q = position_of_point[p]
        xi = positions[q, 0]
        eta = positions[q, 1]
        _fill_line(bx, bu, xi, eta, line)
        if bent:
            dE = edge_sampled_strain(s55, s57, s77, s66, s67, xi, eta)
        T = 0.0  # sum over the line of w |det J| sigma : k k
        term = terms[p]
        # sums over the line of P = w |det J| sigma J^-T (F S J^-T if finite) and of zeta P
        m = (0.0,) * 9
        n = (0.0,) * 6
        if term == TERM_NORMAL:
            # the enhanced thickness strain of this line, alpha g / |det J| at each point,
            # condensed in the same pass: its stationarity sum w g szz(alpha) = 0 is linear in
            # alpha, so alpha = -r / h from the compatible stress, and the stress it adds,
            # C[:, 2] alpha g / |det J|, adds alpha (mc, nc) to the line's moments
            r = 0.0
            h = 0.0
            Tc = 0.0  # T per unit alpha
            mc = (0.0,) * 9
            nc = (0.0,) * 6
            for pp in range(p, end):
                z = zeta[pp]
                wd, K, H, strain = _point_kinematics(line, z, weights[pp], maps, pp - start, finite)
                if bent and maps is None:
                    strain = corrected_strain(strain, dE, K)
                exx, eyy, ezz, _, _, gxy = strain
                k = ply_of_point[pp]
                sxx = stiffness[k, 0, 0] * exx + stiffness[k, 0, 1] * eyy
                sxx += stiffness[k, 0, 2] * ezz + stiffness[k, 0, 5] * gxy
                syy = stiffness[k, 1, 0] * exx + stiffness[k, 1, 1] * eyy
                syy += stiffness[k, 1, 2] * ezz + stiffness[k, 1, 5] * gxy
                szz = stiffness[k, 2, 0] * exx + stiffness[k, 2, 1] * eyy
                szz += stiffness[k, 2, 2] * ezz + stiffness[k, 2, 5] * gxy
                sxy = stiffness[k, 5, 0] * exx + stiffness[k, 5, 1] * eyy
                sxy += stiffness[k, 5, 2] * ezz + stiffness[k, 5, 5] * gxy
                density = 0.5 * (sxx * exx + syy * eyy + szz * ezz + sxy * gxy)
                if opening_scale is not None:
                    s22 = opening[k, 0] * exx + opening[k, 1] * eyy
                    s22 += opening[k, 2] * ezz + opening[k, 5] * gxy
                    # branch-free: zero for a closed crack and for an undamaged ply
                    scale = opening_scale[k] * max(s22, 0.0)
                    sxx -= scale * opening[k, 0]
                    syy -= scale * opening[k, 1]
                    szz -= scale * opening[k, 2]
                    sxy -= scale * opening[k, 5]
                    density -= 0.5 * scale * s22
                energy += wd * density
                P = _normal_stress_map(wd * sxx, wd * syy, wd * szz, wd * sxy, K)
                if bent:
                    T += stress_on_director(P, K)
                m, n = _add_point_moments(m, n, _first_piola(P, H, finite), z)
                if maps is None:  # the damaged kernel condenses its strains in ``maps``
                    wg = weights[pp] * enhanced_mode[pp]
                    r += wg * szz
                    h += wg * wg * stiffness[k, 2, 2] / wd
                    Pc = _normal_stress_map(
                        wg * stiffness[k, 0, 2],
                        wg * stiffness[k, 1, 2],
                        wg * stiffness[k, 2, 2],
                        wg * stiffness[k, 5, 2],
                        K,
                    )
                    if bent:
                        Tc += stress_on_director(Pc, K)
                    mc, nc = _add_point_moments(mc, nc, _first_piola(Pc, H, finite), z)
            if h > 0.0:
                alpha = -r / h
                energy -= 0.5 * r * r / h  # alpha r + 1/2 alpha^2 h
                m, n = _add_scaled_moments(m, n, alpha, mc, nc)
                T += alpha * Tc
        else:
            for pp in range(p, end):
                z = zeta[pp]
                wd, K, H, strain = _point_kinematics(line, z, weights[pp], maps, pp - start, finite)
                if bent and maps is None:
                    strain = corrected_strain(strain, dE, K)
                _, _, _, gyz, gxz, _ = strain
                k = ply_of_point[pp]
                c_xz = stiffness[k, 4, 4] if term == TERM_SHEAR_XZ else 0.0
                c_yz = stiffness[k, 3, 3] if term == TERM_SHEAR_YZ else 0.0
                c_cross = stiffness[k, 3, 4] if term == TERM_SHEAR_CROSS else 0.0
                sxz = c_xz * gxz + c_cross * gyz
                syz = c_yz * gyz + c_cross * gxz
                energy += 0.5 * wd * (sxz * gxz + syz * gyz)
                P = _shear_stress_map(wd * syz, wd * sxz, K)
                if bent:
                    T += stress_on_director(P, K)
                m, n = _add_point_moments(m, n, _first_piola(P, H, finite), z)
        _add_line_moments(f_out, xi, eta, m, n)
        if bent:
            w = work_weights(T, xi, eta)
            W = (W[0] + w[0], W[1] + w[1], W[2] + w[2], W[3] + w[3], W[4] + w[4], W[5] + w[5])
        p = end
    if bent:
        add_correction_forces(f_out, bx, bu, W, finite)
    # back to the vertices: f_a = sum over m containing a of (-1)^|m - a| F_m (transposed
    # butterfly)
    for d in range(3):
        bit = 1 << d
        for m in range(8):
            if m & bit:
                for i in range(3):
                    f_out[m ^ bit, i] -= f_out[m, i]
    return energy


def solid_shell_force(
    X: np.ndarray,
    u: np.ndarray,
    zeta: np.ndarray,
    weights: np.ndarray,
    terms: np.ndarray,
    ply_of_point: np.ndarray,
    position_of_point: np.ndarray,
    positions: np.ndarray,
    stiffness: np.ndarray,
    enhanced_mode: np.ndarray,
    f_out: np.ndarray,
    finite: bool = False,
) -> float:
    """Internal force (N) of one layered solid-shell (sub)element into ``f_out`` (8, 3),
    overwritten; returns its strain energy (mJ = N mm).

    ``X``, ``u``: (8, 3) vertex coordinates and displacements (mm), DOLFINx vertex order. The
    remaining inputs are the fields of a ``PackedRule`` (``pack_rule``), so the usual call is
    ``solid_shell_force(X, u, *rule, f_out)``. Small strain (or, ``finite=True``, total
    Lagrangian), selective (ANS-equivalent) rule; see the module docstring.
    ``solid_shell_forces`` with one element (one compiled kernel fewer)."""
    rule = PackedRule(
        zeta, weights, terms, ply_of_point, position_of_point, positions, stiffness, enhanced_mode
    )
    return solid_shell_forces(
        np.ascontiguousarray(X, dtype=np.float64)[None],
        np.ascontiguousarray(u, dtype=np.float64)[None],
        np.zeros(1, dtype=np.int64),
        *concatenate_rules([rule]),
        f_out[None],
        bool(finite),
    )


@njit(cache=True, **KERNEL_OPTIONS)
def solid_shell_forces(
    X_all,
    u_all,
    rule_of_element,
    rule_offsets,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    f_all,
    finite,
):
    """Internal forces (N) of many (sub)elements into ``f_all`` (ne, 8, 3), overwritten; returns
    their total strain energy (mJ). ``finite``: total Lagrangian kinematics.

    ``X_all``, ``u_all``: (ne, 8, 3) vertex coordinates and displacements (mm), DOLFINx vertex
    order. Element e uses the points ``rule_offsets[r]:rule_offsets[r + 1]`` with
    ``r = rule_of_element[e]`` (elements with the same layup may share a rule; give each element
    its own rule with ``rule_of_element = arange(ne)``). The remaining inputs are the fields of a
    ``PackedRules`` (``concatenate_rules``): ``solid_shell_forces(X, u, rule_of_element,
    *rules, f_all, finite)``, ``finite`` a bool every time (another type compiles it again)."""
    work = np.empty((2, 8, 3))
    line = np.empty((4, 3, 3))
    energy = 0.0
    for e in range(X_all.shape[0]):
        start = rule_offsets[rule_of_element[e]]
        stop = rule_offsets[rule_of_element[e] + 1]
        energy += element_force_kernel(
            X_all[e],
            u_all[e],
            start,
            stop,
            zeta,
            weights,
            terms,
            ply_of_point,
            position_of_point,
            positions,
            stiffness,
            enhanced_mode,
            work,
            line,
            f_all[e],
            None,
            None,
            None,
            finite,
        )
    return energy


@njit(cache=True, **KERNEL_OPTIONS)
def enhanced_parameter_maps(
    X_all,
    rule_of_element,
    rule_offsets,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    out,
):
    """The small-strain enhanced thickness strain parameters as linear maps of the nodal
    displacements: alpha_k = sum over (a, i) of out[e, k, a, i] u[a, i] for undamaged
    (sub)elements with vertices X_all (ne, 8, 3), lines in the rule's order, ``out``
    (ne, 4, 8, 3); the parameters ``solid_shell_forces`` condenses (zero for a rule without the
    enhanced strain). Element e uses rule ``rule_of_element[e]`` of the ``PackedRules`` whose
    fields follow: ``enhanced_parameter_maps(X_all, rule_of_element, *rules, out)``.
    alpha_k = -r_k / h_k with r_k = sum w g szz: its gradient is the line's force of the
    stress C[:, 2] w g per point, the same moments as the force kernel's enhanced term
    (``element_force_kernel``). Geometry only: the UFL cells' maps are computed once per
    mesh, then a matrix-vector product per element and step."""
    work = np.empty((2, 8, 3))
    line = np.empty((4, 3, 3))
    f = np.empty((8, 3))
    zero = np.zeros((8, 3))
    for e in range(X_all.shape[0]):
        start = rule_offsets[rule_of_element[e]]
        stop = rule_offsets[rule_of_element[e] + 1]
        _monomials(X_all[e], work[0])
        _monomials(zero, work[1])
        bent = directors_bend(work[0])
        for k in range(out.shape[1]):
            for a in range(8):
                for i in range(3):
                    out[e, k, a, i] = 0.0
        n_lines = 0
        p = start
        while p < stop:
            end = _line_end(position_of_point, p, stop)
            if terms[p] == TERM_NORMAL:
                q = position_of_point[p]
                xi = positions[q, 0]
                eta = positions[q, 1]
                _fill_line(work[0], work[1], xi, eta, line)
                h = 0.0
                Tc = 0.0  # the residual's part through the edge-sampled thickness strain
                m = (0.0,) * 9
                n = (0.0,) * 6
                for pp in range(p, end):
                    z = zeta[pp]
                    wd, K, _, _ = _point_kinematics(line, z, weights[pp], None, 0, False)
                    k = ply_of_point[pp]
                    wg = weights[pp] * enhanced_mode[pp]
                    h += wg * wg * stiffness[k, 2, 2] / wd
                    P = _normal_stress_map(
                        wg * stiffness[k, 0, 2],
                        wg * stiffness[k, 1, 2],
                        wg * stiffness[k, 2, 2],
                        wg * stiffness[k, 5, 2],
                        K,
                    )
                    m, n = _add_point_moments(m, n, P, z)
                    Tc += stress_on_director(P, K)
                for a in range(8):
                    for i in range(3):
                        f[a, i] = 0.0
                _add_line_moments(f, xi, eta, m, n)
                if bent:
                    add_correction_forces(f, work[0], work[1], work_weights(Tc, xi, eta), False)
                for d in range(3):
                    bit = 1 << d
                    for c in range(8):
                        if c & bit:
                            for i in range(3):
                                f[c ^ bit, i] -= f[c, i]
                if h > 0.0:
                    for a in range(8):
                        for i in range(3):
                            out[e, n_lines, a, i] = -f[a, i] / h
                n_lines += 1
            p = end


@njit(cache=True)
def solid_shell_lumped_mass(X, points, weights, ply_of_point, density, m_out):
    """Row-sum lumped nodal masses (tonne) of one (sub)element into ``m_out`` (8,), overwritten:
    m_a = sum_points rho * N_a * |det J| * w. ``X`` (8, 3) in mm, DOLFINx vertex order; the other
    inputs are the fields of a ``PackedMassRule`` (``pack_mass_rule``):
    ``solid_shell_lumped_mass(X, *mass_rule, m_out)``. Their total is the (sub)element's mass.
    Called on refinement only, so it is plain rather than fast."""
    for a in range(8):
        m_out[a] = 0.0
    values = np.empty(8)
    J = np.empty((3, 3))
    for p in range(weights.shape[0]):
        J[:, :] = 0.0
        for a in range(8):
            n = 1.0
            g0 = 1.0
            g1 = 1.0
            g2 = 1.0
            for d in range(3):
                corner = (a >> d) & 1
                x = points[p, d] if corner == 1 else 1.0 - points[p, d]
                slope = 1.0 if corner == 1 else -1.0
                n *= x
                g0 *= slope if d == 0 else x
                g1 *= slope if d == 1 else x
                g2 *= slope if d == 2 else x
            values[a] = n
            for i in range(3):
                J[i, 0] += X[a, i] * g0
                J[i, 1] += X[a, i] * g1
                J[i, 2] += X[a, i] * g2
        det = (
            J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1])
            - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
            + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0])
        )
        scale = density[ply_of_point[p]] * abs(det) * weights[p]
        for a in range(8):
            m_out[a] += scale * values[a]


@njit(cache=True)
def solid_shell_lumped_masses(X_all, points, weights, ply_of_point, density):
    """(n, 8) row-sum lumped nodal masses (tonne) of n (sub)elements sharing one
    ``PackedMassRule``: ``solid_shell_lumped_mass`` for each of ``X_all`` (n, 8, 3)."""
    out = np.empty((X_all.shape[0], 8))
    for e in range(X_all.shape[0]):
        solid_shell_lumped_mass(X_all[e], points, weights, ply_of_point, density, out[e])
    return out


# ---------------------------------------------------------------------------------------------
# damage-aware kernels (matrix damage of ``ply_damage``)
#
# Layout. The plies of a packed rule are numbered k (``ply_of_point``, rows of ``stiffness``);
# a ``ply_damage.PackedPlyDamage`` built for the same plies has the same rows. An element whose
# points are start:stop holds the contiguous plies k0 = ply_of_point[start] .. k1 =
# ply_of_point[stop - 1] (a rule's first line starts at its lowest ply, its last line ends at
# its highest: ``PackedRule``); its rule-local ply j = k - k0 reads its crack band widths (2,)
# and its damage state (N_STATE floats, updated in place) from row j of the arrays given for that
# element. The batched kernel takes them per element from ``band_width[state_row[e],
# first_ply[e] + j]`` and ``damage_state[state_row[e], first_ply[e] + j]``: a cell's row holds
# all plies of its laminate, so an ESL element (first_ply 0), the subelements of a refined cell
# (first_ply = index of their lowest ply) and a layerwise cell holding a sublaminate all share
# one state per (cell, laminate ply), which therefore survives refinement.
#
# Per element: (1) each ply's mean strain (shell frame; normal components and gamma_xy over
# the ply's "normal" points, gamma_xz over its shear_xz points, gamma_yz over its shear_yz
# points, weighted by w |det J|); (2) its effective material-frame stress C0 T eps and the
# damage update; (3) its shell-frame secant stiffness (1 - d_f) (stiffness[k] - d (open A0 +
# A1)) into a scratch copy (a plain copy while d = d_f = 0); (4) ``element_force_kernel`` with
# that copy, which equals the elastic kernel's force (to round-off) while nothing is damaged.
#
# Erosion (``erode``): an element all of whose plies' fibres have failed (d_f = 1), or crushed
# (``add_damaged_subelement_forces``), is removed: its force is no longer computed, its nodes
# keep their mass. The strain energy it held when it went (the RESIDUAL share of its plies'
# stiffness when its fibres broke, all of it when it was crushed) is booked in its plies'
# S_ERODED, per unit of their volume, so that the energy balance from the states still closes.
# A subelement whose plies' fibres all broke before its cell refined leaves at the refinement:
# its energy goes with the refinement's (``refinement_energy``).
#
# Consequences of one secant stiffness per ply: a strain gradient inside a damaging ply
# (bending) releases the mean over its points of eps.A.eps, more than that of its mean strain;
# the law is given that mean (``_ply_release_rates``), so that its crack band dissipates G_c
# per crack area as the element releases it; the force jumps where a damaged ply's mean
# transverse stress changes sign (crack closing). Cost: the strain pass repeats the Jacobian
# work of the force pass.


# Rows of the per-point scratch of the damaged kernel (``maps``, (N_MAPS, >= points of a rule)):
# w |det J|, then K = J^-1 row-major (rows 1..9), then the strain (rows 10..15, ``_strain``'s
# order). The force pass reads them instead of recomputing.
N_MAPS = 16


@njit(inline="always", **KERNEL_OPTIONS)
def _point_maps(X, u, start, stop, zeta, weights, position_of_point, positions, work, line, maps):
    """w |det J|, J^-1 and the small strain of every point of one element (points start:stop)
    into ``maps`` (column p - start; layout at ``N_MAPS``): the compatible strain, with the
    edge-sampled thickness strain where the directors bend (``assumed_strain``)."""
    bx = work[0]
    bu = work[1]
    _monomials(X, bx)
    _monomials(u, bu)
    bent = directors_bend(bx)
    s55 = s57 = s77 = s66 = s67 = 0.0
    if bent:
        s55, s57, s77, s66, s67 = cell_strain_coefficients(bx, bu, False)
    dE = 0.0
    p = start
    while p < stop:
        end = _line_end(position_of_point, p, stop)
        q = position_of_point[p]
        _fill_line(bx, bu, positions[q, 0], positions[q, 1], line)
        if bent:
            dE = edge_sampled_strain(s55, s57, s77, s66, s67, positions[q, 0], positions[q, 1])
        # a vectorised loop into contiguous rows
        for pp in range(p, end):
            z = zeta[pp]
            det, K = _inverse_jacobian(line, z)
            strain = _strain(_matmul3(_displacement_gradient(line, z), K), False)
            if bent:
                strain = corrected_strain(strain, dE, K)
            row = pp - start
            maps[0, row] = weights[pp] * abs(det)
            for a in range(9):
                maps[1 + a, row] = K[a]
            for a in range(6):
                maps[10 + a, row] = strain[a]
        p = end


# Newton steps of the enhanced strain's condensation in a line with open matrix cracks (the
# thickness stress is piecewise linear in alpha: a step is exact once the open points stay)
CONDENSATION_STEPS = 8


@njit(cache=True, **KERNEL_OPTIONS)  # called per element: compiled once, not inlined
def _condense_enhanced_strain(
    start,
    stop,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    stiffness,
    enhanced_mode,
    opening,
    opening_scale,
    maps,
):
    """Add the condensed enhanced thickness strain alpha g / |det J| of each "normal" line to
    the strains in ``maps`` (``_point_maps``): alpha makes sum w g szz vanish on the line, with
    ``stiffness`` and, where ``opening_scale`` > 0 and the crack is open, its opening (as in
    ``element_force_kernel``). Lines without the enhanced strain (g = 0) are left as they
    are. Whatever enhanced strain ``maps`` already holds is corrected, not added to."""
    p = start
    while p < stop:
        end = _line_end(position_of_point, p, stop)
        if terms[p] == TERM_NORMAL:
            previous = -1
            for _ in range(CONDENSATION_STEPS):
                r = 0.0
                h = 0.0
                open_points = 0
                can_open = False  # a cracked ply on the line: its points may open or close
                for pp in range(p, end):
                    row = pp - start
                    k = ply_of_point[pp]
                    exx = maps[10, row]
                    eyy = maps[11, row]
                    ezz = maps[12, row]
                    gxy = maps[15, row]
                    szz = stiffness[k, 2, 0] * exx + stiffness[k, 2, 1] * eyy
                    szz += stiffness[k, 2, 2] * ezz + stiffness[k, 2, 5] * gxy
                    dszz = stiffness[k, 2, 2]
                    if opening_scale is not None and opening_scale[k] > 0.0:
                        can_open = True
                        s22 = opening[k, 0] * exx + opening[k, 1] * eyy
                        s22 += opening[k, 2] * ezz + opening[k, 5] * gxy
                        if s22 > 0.0:
                            szz -= opening_scale[k] * s22 * opening[k, 2]
                            dszz -= opening_scale[k] * opening[k, 2] * opening[k, 2]
                            open_points += (pp - p + 1) * (pp - p + 1)
                    wg = weights[pp] * enhanced_mode[pp]
                    r += wg * szz
                    h += wg * wg * dszz / maps[0, row]
                if h <= 0.0 or open_points == previous:
                    break
                previous = open_points
                alpha = -r / h
                for pp in range(p, end):
                    row = pp - start
                    maps[12, row] += alpha * weights[pp] * enhanced_mode[pp] / maps[0, row]
                if not can_open:  # linear: that step was exact, a second would only check it
                    break
        p = end


@njit(inline="always", **KERNEL_OPTIONS)
def _normal_energy_at(maps, row, k, stiffness, opening, opening_scale):
    """w |det J| times the "normal" term's strain energy density at the point in column
    ``row`` of ``maps`` (ply k's ``stiffness``, its crack opened where the point's s22 > 0, as
    ``element_force_kernel`` computes it): mJ."""
    e = (maps[10, row], maps[11, row], maps[12, row], maps[15, row])
    density = 0.0
    for a, i in enumerate((0, 1, 2, 5)):
        s = 0.0
        for b, j in enumerate((0, 1, 2, 5)):
            s += stiffness[k, i, j] * e[b]
        density += 0.5 * s * e[a]
    s22 = opening[k, 0] * e[0] + opening[k, 1] * e[1] + opening[k, 2] * e[2]
    s22 += opening[k, 5] * e[3]
    density -= 0.5 * opening_scale[k] * max(s22, 0.0) ** 2
    return maps[0, row] * density


@njit(cache=True, **KERNEL_OPTIONS)  # called per element: compiled once, not inlined
def _normal_energy(start, stop, terms, ply_of_point, stiffness, opening, opening_scale, maps):
    """Strain energy (mJ) of the "normal" term of one element from the strains in ``maps``,
    with ``stiffness`` and the crack opening (as ``element_force_kernel`` computes it)."""
    energy = 0.0
    for pp in range(start, stop):
        if terms[pp] != TERM_NORMAL:
            continue
        row = pp - start
        energy += _normal_energy_at(maps, row, ply_of_point[pp], stiffness, opening, opening_scale)
    return energy


@njit(inline="always", **KERNEL_OPTIONS)
def _ply_normal_energies(
    start, stop, terms, ply_of_point, stiffness, opening, opening_scale, maps, out
):
    """Strain energy (mJ) of each ply's "normal" term in one element, with its secant
    ``stiffness`` and crack ``opening_scale`` (as ``_secant_stiffness`` left them; the density
    ``_normal_energy`` integrates), into ``out[j]`` for rule-local ply j, in one pass over the
    points. The fibres' energy release rate is its mean over the ply (``_fibre_energy``)."""
    k0 = ply_of_point[start]
    for j in range(ply_of_point[stop - 1] - k0 + 1):
        out[j] = 0.0
    for pp in range(start, stop):
        if terms[pp] != TERM_NORMAL:
            continue
        row = pp - start
        k = ply_of_point[pp]
        out[k - k0] += _normal_energy_at(maps, row, k, stiffness, opening, opening_scale)


@njit(inline="always", **KERNEL_OPTIONS)
def _ply_release_rates(
    start, stop, terms, ply_of_point, maps, strain_to_stress, ply_params, volumes, out
):
    """The matrix's energy release rates of each ply of one element as the element releases
    them (it softens every point of the ply with the one damage): the means over the ply's
    "normal" points, weighted by w |det J| (their sum ``volumes[j, 0]``, as ``_ply_means``
    left it), of ``ply_damage.matrix_release_rates``, each point's crack open where its own
    s22 > 0 (as ``element_force_kernel`` opens it), into out[j, 0], out[j, 1] (MPa) for
    rule-local ply j (``ply_damage.ply_damage_update``'s ``point_rates``). Where the strain
    varies through the ply these exceed the rates of its mean strain (by 4/3 for a strain
    rising linearly from zero across it)."""
    k0 = ply_of_point[start]
    n_local = ply_of_point[stop - 1] - k0 + 1
    for j in range(n_local):
        out[j, 0] = 0.0
        out[j, 1] = 0.0
    for pp in range(start, stop):
        if terms[pp] != TERM_NORMAL:
            continue
        row = pp - start
        k = ply_of_point[pp]
        e = (maps[10, row], maps[11, row], maps[12, row], maps[15, row])
        s22 = 0.0
        s12 = 0.0
        for b, i in enumerate((0, 1, 2, 5)):
            s22 += strain_to_stress[k, 1, i] * e[b]
            s12 += strain_to_stress[k, 5, i] * e[b]
        y_normal, y_in_plane = matrix_release_rates(s22, s12, ply_params[k])
        out[k - k0, 0] += maps[0, row] * y_normal
        out[k - k0, 1] += maps[0, row] * y_in_plane
    for j in range(n_local):
        out[j, 0] /= volumes[j, 0]
        out[j, 1] /= volumes[j, 0]


@njit(inline="always", **KERNEL_OPTIONS)
def _fibre_energy(k, j, stiffness, normal_energy, strains, volumes, root_xz, root_yz):
    """Strain energy density (MPa) of rule-local ply j (ply k of the rule) of one element: the
    mean of its "normal" term's (``_ply_normal_energies``) plus that of its mean transverse
    shears (which the rule samples at their own points; a ply's stiffness couples them with
    nothing else) with the ply's shear factors in the element (``root_xz``, ``root_yz``: their
    square roots). ``strains``, ``volumes``: as ``_ply_means`` left them. The mean of
    the energy, not the energy of the mean strain: fibre damage scales every point of the ply,
    so that it releases this (a ply bent within its thickness holds more than its mean strain
    says)."""
    g_yz, g_xz = root_yz * strains[j, 3], root_xz * strains[j, 4]
    shear = 0.5 * (
        stiffness[k, 3, 3] * g_yz * g_yz
        + 2.0 * stiffness[k, 3, 4] * g_yz * g_xz
        + stiffness[k, 4, 4] * g_xz * g_xz
    )
    return normal_energy[j] / volumes[j, 0] + shear


@njit(inline="always", **KERNEL_OPTIONS)
def _ply_means(start, stop, terms, ply_of_point, maps, strains, volumes):
    """Mean shell-frame strain (xx, yy, zz, yz, xz, xy; engineering shears) of each ply of one
    element (points start:stop) into ``strains[j]``, j = ply_of_point[p] - ply_of_point[start],
    from the strains in ``maps``: xx, yy, zz, xy averaged over the ply's "normal" points, xz
    over its shear_xz points, yz over its shear_yz points, each weighted by w |det J|.
    Scratch: ``volumes`` (>= n_plies, 3)."""
    k0 = ply_of_point[start]
    n_local = ply_of_point[stop - 1] - k0 + 1
    for j in range(n_local):
        for a in range(6):
            strains[j, a] = 0.0
        for a in range(3):
            volumes[j, a] = 0.0
    # _strain's order is (xx, yy, zz, yz, xz, xy): maps rows 10..15 in the Voigt order
    for pp in range(start, stop):
        row = pp - start
        j = ply_of_point[pp] - k0
        term = terms[pp]
        wd = maps[0, row]
        if term == TERM_NORMAL:
            strains[j, 0] += wd * maps[10, row]
            strains[j, 1] += wd * maps[11, row]
            strains[j, 2] += wd * maps[12, row]
            strains[j, 5] += wd * maps[15, row]
            volumes[j, 0] += wd
        elif term == TERM_SHEAR_XZ:
            strains[j, 4] += wd * maps[14, row]
            volumes[j, 1] += wd
        elif term == TERM_SHEAR_YZ:
            strains[j, 3] += wd * maps[13, row]
            volumes[j, 2] += wd
    for j in range(n_local):
        strains[j, 0] /= volumes[j, 0]
        strains[j, 1] /= volumes[j, 0]
        strains[j, 2] /= volumes[j, 0]
        strains[j, 5] /= volumes[j, 0]
        strains[j, 4] /= volumes[j, 1]
        strains[j, 3] /= volumes[j, 2]


@njit(inline="always", **KERNEL_OPTIONS)
def _secant_stiffness(
    k0, n_local, state, stiffness, degradation, ply_params, degraded, dirty, opening_scale
):
    """Each ply's closed-crack secant stiffness into ``degraded`` and its crack opening
    factor into ``opening_scale``, from its damage ``state`` (rule-local rows)."""
    for j in range(n_local):
        k = k0 + j
        d = (1.0 - RESIDUAL) * state[j, S_D]
        kept = 1.0 - (1.0 - RESIDUAL) * state[j, S_DF]  # the share the fibres still carry
        if d == 0.0 and kept == 1.0:
            opening_scale[k] = 0.0
            if dirty[k]:
                for a in range(6):
                    for b in range(6):
                        degraded[k, a, b] = stiffness[k, a, b]
                dirty[k] = False
            continue
        dirty[k] = True
        # the closed-crack stiffness; the kernel opens the crack point by point
        for a in range(6):
            for b in range(6):
                degraded[k, a, b] = kept * (stiffness[k, a, b] - d * degradation[k, 1, a, b])
        opening_scale[k] = kept * d / ply_params[k, P_C22]


@njit(**KERNEL_OPTIONS)  # (not inlined: called twice by the damaged kernel, see above)
def _condense_with_damage(
    start,
    stop,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    stiffness,
    enhanced_mode,
    strain_to_stress,
    degradation,
    ply_params,
    state,
    degraded,
    dirty,
    opening_scale,
    maps,
    measure,
):
    """The plies' secant stiffness from their damage ``state`` (``_secant_stiffness``), then
    the strains in ``maps`` condensed with it (``_condense_enhanced_strain``). Returns the
    normal-term energy the condensation released when ``measure`` (else 0)."""
    k0 = ply_of_point[start]
    n_local = ply_of_point[stop - 1] - k0 + 1
    _secant_stiffness(
        k0, n_local, state, stiffness, degradation, ply_params, degraded, dirty, opening_scale
    )
    opening = strain_to_stress[:, 1, :]
    before = 0.0
    if measure:
        before = _normal_energy(
            start, stop, terms, ply_of_point, degraded, opening, opening_scale, maps
        )
    _condense_enhanced_strain(
        start,
        stop,
        weights,
        terms,
        ply_of_point,
        position_of_point,
        degraded,
        enhanced_mode,
        opening,
        opening_scale,
        maps,
    )
    if not measure:
        return 0.0
    return before - _normal_energy(
        start, stop, terms, ply_of_point, degraded, opening, opening_scale, maps
    )


@njit(inline="always", **KERNEL_OPTIONS)
def _element_force_damaged(
    X,
    u,
    start,
    stop,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    strain_to_stress,
    degradation,
    ply_params,
    band_width,
    state,
    degraded,
    dirty,
    opening_scale,
    work,
    line,
    maps,
    strains,
    volumes,
    sigma,
    normal_energy,
    release,
    f_out,
    update,
):
    """Damage update (unless ``update`` is False: the damage as it is) and force of one
    element (points start:stop) into f_out (8, 3); returns the secant strain energy.
    ``band_width`` (n_local, 2) and ``state`` (n_local, N_STATE) are the element's plies' rows
    (rule-local); ``degraded`` is a scratch array shaped like ``stiffness`` (only the
    element's rows are written) and ``dirty`` (len(stiffness),) bool says which of its rows
    differ from ``stiffness`` (elements sharing a rule share rows). Other scratch: ``maps``
    (N_MAPS, >= stop - start), ``strains`` (>= n_local, 6), ``volumes`` (>= n_local, 3),
    ``sigma`` (6,), ``normal_energy`` (>= n_local,), ``release`` (>= n_local, 2)."""
    _point_maps(X, u, start, stop, zeta, weights, position_of_point, positions, work, line, maps)
    k0 = ply_of_point[start]
    n_local = ply_of_point[stop - 1] - k0 + 1
    # the damage is driven by the strain condensed with the plies' damage so far, and the
    # force uses the strain condensed again with the updated damage
    _condense_with_damage(
        start,
        stop,
        weights,
        terms,
        ply_of_point,
        position_of_point,
        stiffness,
        enhanced_mode,
        strain_to_stress,
        degradation,
        ply_params,
        state,
        degraded,
        dirty,
        opening_scale,
        maps,
        False,
    )
    _ply_means(start, stop, terms, ply_of_point, maps, strains, volumes)
    fibres = False  # does a ply of the element break its fibres?
    if update:
        _ply_release_rates(
            start, stop, terms, ply_of_point, maps, strain_to_stress, ply_params, volumes, release
        )
        for j in range(n_local):
            fibres = fibres or ply_params[k0 + j, F_GFT] > 0.0
    if fibres:
        _ply_normal_energies(
            start,
            stop,
            terms,
            ply_of_point,
            degraded,
            strain_to_stress[:, 1, :],
            opening_scale,
            maps,
            normal_energy,
        )
    grown = 0.0
    for j in range(n_local):
        k = k0 + j
        # the ply's stress is that of its strain with the transverse shears its element's
        # energy carries: the shear terms' weights hold the ply's shear factors m
        # (solid_shell.shear_weights), so the shear strains times sqrt(m) (the ply's share of
        # the laminate's shear flow, materials.laminate.ply_shear_factors); a one-ply
        # element has none (its volumes' ratio is 1 but for the in-plane rules' |det J|)
        root_xz = root_yz = 1.0
        if n_local > 1:
            root_xz = math.sqrt(volumes[j, 1] / volumes[j, 0])
            root_yz = math.sqrt(volumes[j, 2] / volumes[j, 0])
        for a in range(6):
            s = 0.0
            for b in range(6):
                e = strains[j, b]
                if b == 3:
                    e *= root_yz
                elif b == 4:
                    e *= root_xz
                s += strain_to_stress[k, a, b] * e
            sigma[a] = s
        energy_density = 0.0  # the fibres' energy release rate needs it
        if fibres and ply_params[k, F_GFT] > 0.0:  # the ply's, its fibres intact: / share kept
            energy_density = _fibre_energy(
                k, j, degraded, normal_energy, strains, volumes, root_xz, root_yz
            ) / (1.0 - (1.0 - RESIDUAL) * state[j, S_DF])
        d_old = state[j, S_D]
        d_fibre_old = state[j, S_DF]
        if update:
            ply_damage_update(
                sigma, energy_density, ply_params[k], band_width[j], state[j], release[j]
            )
        # the ply's strain is used: its growth instead (matrix, fibre)
        strains[j, 1] = state[j, S_DF] - d_fibre_old
        strains[j, 0] = state[j, S_D] - d_old + strains[j, 1]
        grown += strains[j, 0]
    # Where damage grew, the enhanced strain relaxes to the new stiffness: at fixed nodes the
    # strain energy drops by more than the damage law's increments (the condensed energy is
    # concave in the damage). That drop is dissipation too; book it on the plies that grew,
    # in proportion to their growth, so that the energy balances from the states and from the
    # work agree. Where nothing grew, the strain was condensed with the stiffness it keeps.
    if grown > 0.0:
        relaxed = _condense_with_damage(
            start,
            stop,
            weights,
            terms,
            ply_of_point,
            position_of_point,
            stiffness,
            enhanced_mode,
            strain_to_stress,
            degradation,
            ply_params,
            state,
            degraded,
            dirty,
            opening_scale,
            maps,
            True,
        )
        for j in range(n_local):
            share = relaxed * (strains[j, 0] / grown) / volumes[j, 0]
            state[j, S_DISSIPATED] += share
            if strains[j, 1] > 0.0:
                state[j, S_FIBRE_DISSIPATED] += share * strains[j, 1] / strains[j, 0]
    return element_force_kernel(
        X,
        u,
        start,
        stop,
        zeta,
        weights,
        terms,
        ply_of_point,
        position_of_point,
        positions,
        degraded,
        enhanced_mode,
        work,
        line,
        f_out,
        strain_to_stress[:, 1, :],  # the crack opening direction, as in the condensation
        opening_scale,
        maps,
        False,
    )


@njit(inline="always", **KERNEL_OPTIONS)
def _corner_det(P, k, u, moved):
    """det of the three edges leaving corner k of the hexahedron P (8, 3) (DOLFINx order:
    neighbours k ^ 1, k ^ 2, k ^ 4), of P + u if ``moved``."""
    a = k ^ 1
    b = k ^ 2
    c = k ^ 4
    s = 1.0 if moved else 0.0
    x0 = P[a, 0] - P[k, 0] + s * (u[a, 0] - u[k, 0])
    x1 = P[a, 1] - P[k, 1] + s * (u[a, 1] - u[k, 1])
    x2 = P[a, 2] - P[k, 2] + s * (u[a, 2] - u[k, 2])
    y0 = P[b, 0] - P[k, 0] + s * (u[b, 0] - u[k, 0])
    y1 = P[b, 1] - P[k, 1] + s * (u[b, 1] - u[k, 1])
    y2 = P[b, 2] - P[k, 2] + s * (u[b, 2] - u[k, 2])
    z0 = P[c, 0] - P[k, 0] + s * (u[c, 0] - u[k, 0])
    z1 = P[c, 1] - P[k, 1] + s * (u[c, 1] - u[k, 1])
    z2 = P[c, 2] - P[k, 2] + s * (u[c, 2] - u[k, 2])
    return x0 * (y1 * z2 - y2 * z1) - x1 * (y0 * z2 - y2 * z0) + x2 * (y0 * z1 - y1 * z0)


@njit(cache=True, error_model="numpy")
def corner_volume_ratio(X, u):
    """The smallest volume ratio at the 8 corners of a hexahedron with vertices X (8, 3)
    (DOLFINx order) moved by u (8, 3): det of the three edges leaving a corner, deformed over
    reference. A distortion measure that sees what the affine fit of the motion averages out
    (a corner folded over while the element keeps its volume); <= 0 where a corner has turned
    inside out. Scalars only: no allocation."""
    smallest = np.inf
    for k in range(8):
        smallest = min(smallest, _corner_det(X, k, u, True) / _corner_det(X, k, u, False))
    return smallest


@njit(cache=True, error_model="numpy")
def corotated_gradient(X, u, f):
    """Turn the force f (8, 3) of an element computed in its co-rotated frame, the gradient of
    its energy with respect to u_local, into the gradient with respect to the element's
    current positions (in the co-rotated axes), in place: f_a <- f_a - z x G_a, with
    G_a = B^-1 D_a, D_a = X_a - X_c, B = sum_a D_a D_a^T, z = (tr U I - U)^-1 m, U the
    stretch of the affine fit of the motion (F = R U, ``element_rotation``: here the fit of
    y_a = D_a + u_a, the positions as the frame sees them) and m = sum_a y_a x f_a, the
    force's moment about the centre. This is the frame's spin differentiated: R turns by
    w = 2 (tr U I - U)^-1 axial(skew(R^T dF)) under a change dF of the fit, and the energy
    psi(u_local), u_local = R^T (x - x_c) - D, changes by -w.m with it. The result is the
    exact gradient of psi(x): balanced in force and in moment about the centre as the element
    is now (a rigid spin does no work), and its work is the energy's change, so a strained,
    damaged element tumbling neither takes nor gives energy. ``X``, ``u`` (8, 3): the element
    as the kernel saw it (sum_a u_a = 0). Scalars only: no allocation."""
    (Xc0, Xc1, Xc2), _ = _centroids(X, u)
    b00 = b01 = b02 = b11 = b12 = b22 = 0.0
    A00 = A01 = A02 = A10 = A11 = A12 = A20 = A21 = A22 = 0.0  # sum_a y_a D_a^T
    m0 = m1 = m2 = 0.0
    for a in range(8):
        D0, D1, D2 = X[a, 0] - Xc0, X[a, 1] - Xc1, X[a, 2] - Xc2
        y0, y1, y2 = D0 + u[a, 0], D1 + u[a, 1], D2 + u[a, 2]
        b00 += D0 * D0
        b01 += D0 * D1
        b02 += D0 * D2
        b11 += D1 * D1
        b12 += D1 * D2
        b22 += D2 * D2
        A00 += y0 * D0
        A01 += y0 * D1
        A02 += y0 * D2
        A10 += y1 * D0
        A11 += y1 * D1
        A12 += y1 * D2
        A20 += y2 * D0
        A21 += y2 * D1
        A22 += y2 * D2
        m0 += y1 * f[a, 2] - y2 * f[a, 1]
        m1 += y2 * f[a, 0] - y0 * f[a, 2]
        m2 += y0 * f[a, 1] - y1 * f[a, 0]
    _, Bi = _inverse3((b00, b01, b02, b01, b11, b12, b02, b12, b22))
    # U = A B^-1 (symmetric up to the polar iteration's tolerance: its symmetric part)
    U00 = A00 * Bi[0] + A01 * Bi[3] + A02 * Bi[6]
    U11 = A10 * Bi[1] + A11 * Bi[4] + A12 * Bi[7]
    U22 = A20 * Bi[2] + A21 * Bi[5] + A22 * Bi[8]
    U01 = 0.5 * (A00 * Bi[1] + A01 * Bi[4] + A02 * Bi[7] + A10 * Bi[0] + A11 * Bi[3] + A12 * Bi[6])
    U02 = 0.5 * (A00 * Bi[2] + A01 * Bi[5] + A02 * Bi[8] + A20 * Bi[0] + A21 * Bi[3] + A22 * Bi[6])
    U12 = 0.5 * (A10 * Bi[2] + A11 * Bi[5] + A12 * Bi[8] + A20 * Bi[1] + A21 * Bi[4] + A22 * Bi[7])
    trace = U00 + U11 + U22
    det, Ti = _inverse3((trace - U00, -U01, -U02, -U01, trace - U11, -U12, -U02, -U12, trace - U22))
    if not det > 0.0:
        # tr U I - U is positive definite for any stretch; not so only for a fit crushed to a
        # line or turned inside out, whose frame has no derivative: its force stays the one in
        # the frame. Erosion removes such an element in this same call (crushed below
        # ``min_volume_ratio``) before it gets here; without erosion the inversion guard stops
        # the run within 64 steps (its poll) or at the next history row.
        return
    z0 = Ti[0] * m0 + Ti[1] * m1 + Ti[2] * m2
    z1 = Ti[3] * m0 + Ti[4] * m1 + Ti[5] * m2
    z2 = Ti[6] * m0 + Ti[7] * m1 + Ti[8] * m2
    for a in range(8):
        D0, D1, D2 = X[a, 0] - Xc0, X[a, 1] - Xc1, X[a, 2] - Xc2
        G0 = Bi[0] * D0 + Bi[1] * D1 + Bi[2] * D2
        G1 = Bi[3] * D0 + Bi[4] * D1 + Bi[5] * D2
        G2 = Bi[6] * D0 + Bi[7] * D1 + Bi[8] * D2
        f[a, 0] -= z1 * G2 - z2 * G1
        f[a, 1] -= z2 * G0 - z0 * G2
        f[a, 2] -= z0 * G1 - z1 * G0


@njit(inline="always", **KERNEL_OPTIONS)
def _break_fibres(damage_state, row, first, n):
    """Set the fibre damage of plies first .. first + n - 1 of cell row ``row`` to 1 (an
    element eroded by distortion)."""
    for j in range(n):
        damage_state[row, first + j, S_DF] = 1.0


@njit(inline="always", **KERNEL_OPTIONS)
def _book_last_energy(damage_state, row, first, n):
    """Book as eroded the energy density plies first .. first + n - 1 of cell row ``row`` held
    at their last update, (1 - (1 - RESIDUAL) d_f) y_f (y_f = psi_m, the ply's mean secant
    energy density, ``S_YF_LAST``): for an element turned inside out, whose energy now has no
    frame to be computed in (its fibres break next). The last step's work on it is left out."""
    for j in range(n):
        ply = damage_state[row, first + j]
        ply[S_ERODED] += (1.0 - (1.0 - RESIDUAL) * ply[S_DF]) * ply[S_YF_LAST]


@njit(inline="always", **KERNEL_OPTIONS)
def _fibres_broken(damage_state, row, first, n):
    """Whether the fibres of plies first .. first + n - 1 of cell row ``row`` have all failed
    (d_f = 1): the element holding them is eroded. The one erosion rule: the damaged kernel
    skips such an element, ``elements_eroded`` tells the rest of the code which they are."""
    for j in range(n):
        if damage_state[row, first + j, S_DF] < 1.0:
            return False
    return True


@njit(cache=True, **KERNEL_OPTIONS)
def elements_eroded(damage_state, rows, spans, out):
    """out[e] = whether erosion has removed element e, which holds plies spans[e, 0] ..
    spans[e, 1] - 1 of cell row rows[e] (``_fibres_broken``)."""
    for e in range(rows.shape[0]):
        out[e] = _fibres_broken(damage_state, rows[e], spans[e, 0], spans[e, 1] - spans[e, 0])


@njit(cache=True, inline="always")
def _centroids(X, u):
    """(X_c, x_c) of an element's 8 vertices, before and after its motion, as 3-tuples."""
    X0 = X1 = X2 = x0 = x1 = x2 = 0.0
    for a in range(8):
        X0 += 0.125 * X[a, 0]
        X1 += 0.125 * X[a, 1]
        X2 += 0.125 * X[a, 2]
        x0 += 0.125 * (X[a, 0] + u[a, 0])
        x1 += 0.125 * (X[a, 1] + u[a, 1])
        x2 += 0.125 * (X[a, 2] + u[a, 2])
    return (X0, X1, X2), (x0, x1, x2)


@njit(cache=True, error_model="numpy")
def element_rotation(X, u, R):
    """The rotation R (3, 3) of an element with vertices X (8, 3) and displacements u (8, 3),
    in place: the orthogonal factor of the polar decomposition of the affine fit of its
    motion, F = (sum dx dX^T) (sum dX dX^T)^-1 (dX, dx: the vertices about their centroid,
    before and after), by Higham's scaled iteration R <- (g R + R^-T / g) / 2, g = |det
    R|^(-1/3) (the fit is independent of the vertex order, and a rigid rotation Q of the
    deformed element gives Q R). NaN throughout where the fit is not a rotation's (det F <= 0:
    an element turned inside out or flattened) or the iteration does not converge. ``R`` is
    the only storage used: no allocation per element. Returns det F, the volume ratio of the
    fit (NaN if it is not finite)."""
    Xc, xc = _centroids(X, u)
    R[:, :] = 0.0  # first A = sum dx dX^T, then F = A B^-1
    b00 = b01 = b02 = b11 = b12 = b22 = 0.0
    for a in range(8):
        dX0, dX1, dX2 = X[a, 0] - Xc[0], X[a, 1] - Xc[1], X[a, 2] - Xc[2]
        b00 += dX0 * dX0
        b01 += dX0 * dX1
        b02 += dX0 * dX2
        b11 += dX1 * dX1
        b12 += dX1 * dX2
        b22 += dX2 * dX2
        for i in range(3):
            dx = X[a, i] + u[a, i] - xc[i]
            R[i, 0] += dx * dX0
            R[i, 1] += dx * dX1
            R[i, 2] += dx * dX2
    _, K = _inverse3((b00, b01, b02, b01, b11, b12, b02, b12, b22))
    for i in range(3):
        r0, r1, r2 = R[i, 0], R[i, 1], R[i, 2]
        R[i, 0] = r0 * K[0] + r1 * K[3] + r2 * K[6]
        R[i, 1] = r0 * K[1] + r1 * K[4] + r2 * K[7]
        R[i, 2] = r0 * K[2] + r1 * K[5] + r2 * K[8]
    converged = False
    volume_ratio = np.nan
    for iteration in range(POLAR_ITERATIONS):
        det, K = _inverse3(
            (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2])
        )
        if iteration == 0:
            volume_ratio = det
        if not det > 0.0:  # inside out, flat, or NaN already
            break
        g = det ** (-1.0 / 3.0)
        change = 0.0
        for i in range(3):
            for j in range(3):
                new = 0.5 * (g * R[i, j] + K[3 * j + i] / g)  # (R^-T)_ij = (R^-1)_ji
                change = max(change, abs(new - R[i, j]))
                R[i, j] = new
        if change <= POLAR_TOLERANCE:
            converged = True
            break
    if not converged:
        R[:, :] = np.nan
    return volume_ratio


@njit(cache=True)
def turn_rows(F, v, transposed):
    """v[a] <- F v[a] (or F^T v[a] with ``transposed``) for each row a of v (8, 3), in place."""
    for a in range(v.shape[0]):
        v0, v1, v2 = v[a, 0], v[a, 1], v[a, 2]
        for i in range(3):
            if transposed:
                v[a, i] = F[0, i] * v0 + F[1, i] * v1 + F[2, i] * v2
            else:
                v[a, i] = F[i, 0] * v0 + F[i, 1] * v1 + F[i, 2] * v2


@njit(cache=True)
def to_rotated_frame(X, u, R, u_local):
    """u_local = R^T (x - x_c) - (X - X_c) (8, 3): the element's displacement in its
    co-rotated frame, its rigid rotation and translation taken out (no allocation)."""
    Xc, xc = _centroids(X, u)
    for a in range(8):
        d0 = X[a, 0] + u[a, 0] - xc[0]
        d1 = X[a, 1] + u[a, 1] - xc[1]
        d2 = X[a, 2] + u[a, 2] - xc[2]
        for i in range(3):
            u_local[a, i] = R[0, i] * d0 + R[1, i] * d1 + R[2, i] * d2 - (X[a, i] - Xc[i])


def solid_shell_force_damaged(
    X: np.ndarray,
    u: np.ndarray,
    zeta: np.ndarray,
    weights: np.ndarray,
    terms: np.ndarray,
    ply_of_point: np.ndarray,
    position_of_point: np.ndarray,
    positions: np.ndarray,
    stiffness: np.ndarray,
    enhanced_mode: np.ndarray,
    strain_to_stress: np.ndarray,
    degradation: np.ndarray,
    ply_params: np.ndarray,
    band_width: np.ndarray,
    state: np.ndarray,
    f_out: np.ndarray,
    corotational: bool = False,
    update: bool = True,
) -> float:
    """Internal force (N) of one layered solid-shell (sub)element with ply damage into
    ``f_out`` (8, 3), overwritten, updating the damage ``state`` (n_plies, N_STATE) in place;
    returns the secant strain energy (mJ), 1/2 sigma.eps with the damaged stiffness.

    ``X``, ``u`` as in ``solid_shell_force``; then the fields of a ``PackedRule`` and of the
    matching ``ply_damage.PackedPlyDamage`` (``pack_ply_damage`` of the same plies), then the
    crack band widths l_c (mm) of each ply across and along its fibres (n_plies, 2) (one
    width per ply, (n_plies,): the same both ways) and the plies' states:
    ``solid_shell_force_damaged(X, u, *rule, *ply_damage, band_width, state, f_out)``. For a
    subelement spanning laminate plies first:stop of cell row r, pass
    ``band_width[r, first:stop]`` and ``state[r, first:stop]`` (views: updated in place).
    ``corotational``: in the element's co-rotated frame (``add_damaged_subelement_forces``);
    ``update`` False: at the damage so far (the energy and force of a state). The batched
    kernel with one element (one compiled kernel fewer)."""
    rule = PackedRule(
        zeta, weights, terms, ply_of_point, position_of_point, positions, stiffness, enhanced_mode
    )
    none = np.zeros((0, 3))
    f = np.zeros((8, 3))
    zero = np.zeros(1, dtype=np.int64)
    energy = add_damaged_subelement_forces(
        np.arange(8, dtype=np.int32)[None],
        zero,
        zero,
        zero,
        *concatenate_rules([rule]),
        strain_to_stress,
        degradation,
        ply_params,
        _band_rows(band_width, state.shape[0])[None],
        state[None],
        np.ascontiguousarray(X, dtype=np.float64),
        none,
        np.ascontiguousarray(u, dtype=np.float64),
        none,
        f,
        none,
        bool(update),
        bool(corotational),
        False,
        0.0,
        np.zeros(1, dtype=np.int64),
        np.zeros((0, 3, 3)),
    )
    f_out[:] = f
    return energy


def _band_rows(band_width: np.ndarray, n_plies: int) -> np.ndarray:
    """(n_plies, 2) band widths from (n_plies, 2) or one width per ply (n_plies,)."""
    band = np.asarray(band_width, dtype=np.float64)
    if band.ndim == 1:
        band = np.repeat(band[:, None], 2, axis=1)
    if band.shape != (n_plies, 2):
        raise ValueError(f"band widths: expected ({n_plies}, 2) or ({n_plies},), got {band.shape}")
    return np.ascontiguousarray(band)


@njit(cache=True, **KERNEL_OPTIONS)
def add_damaged_subelement_forces(
    element_nodes,
    rule_of_element,
    state_row,
    first_ply,
    rule_offsets,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    strain_to_stress,
    degradation,
    ply_params,
    band_width,
    damage_state,
    X_base,
    X_extra,
    u_base,
    u_extra,
    f_base,
    f_extra,
    update,
    corotational,
    erode,
    min_volume_ratio,
    eroded,
    frames,
):
    """f += sum_e P_e^T f_e over damage-aware (sub)elements, updating their damage (not with
    ``update`` False: the energy of a state at its damage so far); returns the total secant
    strain energy (mJ). Call as ``add_damaged_subelement_forces(nodes,
    rule_of_element, state_row, first_ply, *rules, *ply_damage, band_width, damage_state,
    X_base, X_extra, u_base, u_extra, f_base, f_extra, update, corotational, erode,
    min_volume_ratio, eroded, frames)``, ``nodes`` int32, ``update``, ``corotational`` and
    ``erode`` bools and ``min_volume_ratio`` a float every time: each other argument type
    compiles the kernel again (about a minute). ``erode``: elements whose plies' fibres have
    all failed are removed (the layout notes above ``N_MAPS``: Erosion), and also those
    crushed below ``min_volume_ratio`` at a corner (``corner_volume_ratio``) or, with
    ``corotational``, as a whole (det F of the affine fit of their motion,
    ``element_rotation``): their plies' fibres are broken then (the energy such an element
    held is booked as for the others; one whose fit is inside out, whose energy cannot be
    computed, with the energy its plies held at their last update, ``_book_last_energy``);
    ``eroded`` (1,) int64: the number of elements that went in
    this call is added to it.
    ``frames`` (ne, 3, 3): each element's frame on a
    curved shell (rows its axes, ``element.geometry.cell_frames``): the element is computed
    with its coordinates and displacement in it, F X and F u (after the co-rotation), and its
    force turned back, F^T f; (0, 3, 3): the global frame.

    ``corotational`` (finite kinematics): each element is computed in its co-rotated frame,
    the rotation R of the polar decomposition of the affine fit of its motion
    (``element_rotation``): the small-strain kernel and the damage law see u_local = R^T (x -
    x_c) - (X - X_c) and the force is R f_local (Belytschko's co-rotational approach, as
    explicit codes treat their damaged shells; chosen over a Green-Lagrange form of the damage
    law because the law, its enhanced-strain condensation and its exact dissipation stay the
    small-strain ones, and a rigid rotation leaves u_local, hence the damage and what it
    dissipates, unchanged). The force is the exact gradient of the energy psi(u_local(x)), the
    frame's spin differentiated (``corotated_gradient``), so the states' energy balance holds
    however the element tumbles; the strain measure is the small-strain one of u_local, good
    for the moderate strains of a damaged laminate.

    ``element_nodes`` (ne, 8): combined local node indices (i < n_base = len(X_base): base node
    i, else extra node i - n_base), as in ``assembly``; element e uses rule
    ``rule_of_element[e]`` of the ``PackedRules`` and the concatenated ``PackedPlyDamage``
    (``ply_damage.concatenate_ply_damage``, same order). Its rule-local ply j is laminate ply
    ``first_ply[e] + j`` of the cell row ``state_row[e]``: crack band width
    ``band_width[state_row[e], first_ply[e] + j]`` (band_width (n_rows, n_plies, 2) in mm:
    across and along the fibres, ``ply_damage.BAND_MATRIX``, ``BAND_FIBRE``) and
    state ``damage_state[state_row[e], first_ply[e] + j]`` (damage_state (n_rows, n_plies,
    N_STATE), updated in place). Coordinates, displacements and forces are (n, 3) arrays;
    forces land on ghosts too (reverse scatter by the caller)."""
    n_base = X_base.shape[0]
    n_plies = damage_state.shape[1]
    work = np.empty((2, 8, 3))
    line = np.empty((4, 3, 3))
    degraded = stiffness.copy()
    dirty = np.zeros(stiffness.shape[0], dtype=np.bool_)
    opening_scale = np.zeros(stiffness.shape[0])
    longest = 0
    for r in range(rule_offsets.shape[0] - 1):
        longest = max(longest, rule_offsets[r + 1] - rule_offsets[r])
    maps = np.empty((N_MAPS, longest))
    strains = np.empty((n_plies, 6))
    volumes = np.empty((n_plies, 3))
    normal_energy = np.empty(n_plies)
    release = np.empty((n_plies, 2))
    sigma = np.empty(6)
    X = np.empty((8, 3))
    u = np.empty((8, 3))
    f = np.empty((8, 3))
    R = np.eye(3)
    u_global = np.empty((8, 3))
    f_local = np.empty((8, 3))
    energy = 0.0
    for e in range(element_nodes.shape[0]):
        r = rule_of_element[e]
        start = rule_offsets[r]
        stop = rule_offsets[r + 1]
        n_local = ply_of_point[stop - 1] - ply_of_point[start] + 1
        row = state_row[e]
        lo = first_ply[e]
        if erode and _fibres_broken(damage_state, row, lo, n_local):
            continue  # eroded
        nodes = element_nodes[e]
        gather_nodes(nodes, n_base, X_base, X_extra, X)
        crushed = False
        if corotational:
            gather_nodes(nodes, n_base, u_base, u_extra, u_global)
            volume_ratio = element_rotation(X, u_global, R)
            # erosion by distortion: crushed below the volume ratio (or inside out), as a
            # whole or at a corner
            if erode and update:
                corner = corner_volume_ratio(X, u_global)
                crushed = not (volume_ratio >= min_volume_ratio and corner >= min_volume_ratio)
            if crushed and not np.isfinite(R[0, 0]):  # no frame: nothing to compute with
                _book_last_energy(damage_state, row, lo, n_local)
                _break_fibres(damage_state, row, lo, n_local)
                eroded[0] += 1
                continue
            to_rotated_frame(X, u_global, R, u)
        else:
            gather_nodes(nodes, n_base, u_base, u_extra, u)
            if erode and update:
                crushed = not corner_volume_ratio(X, u) >= min_volume_ratio
        if frames.shape[0] > 0:
            turn_rows(frames[e], X, False)
            turn_rows(frames[e], u, False)
        element_energy = _element_force_damaged(
            X,
            u,
            start,
            stop,
            zeta,
            weights,
            terms,
            ply_of_point,
            position_of_point,
            positions,
            stiffness,
            enhanced_mode,
            strain_to_stress,
            degradation,
            ply_params,
            band_width[row, lo : lo + n_local],
            damage_state[row, lo : lo + n_local],
            degraded,
            dirty,
            opening_scale,
            work,
            line,
            maps,
            strains,
            volumes,
            sigma,
            normal_energy,
            release,
            f,
            update,
        )
        if crushed:
            _break_fibres(damage_state, row, lo, n_local)
        if erode and _fibres_broken(damage_state, row, lo, n_local):
            # eroded now: the energy it held is booked (per unit volume of its plies), its
            # force is gone
            volume = 0.0
            for j in range(n_local):
                volume += volumes[j, 0]
            for j in range(n_local):
                damage_state[row, lo + j, S_ERODED] += element_energy / volume
            eroded[0] += 1
            continue
        energy += element_energy
        if corotational:  # the gradient with respect to x, the frame's spin included
            corotated_gradient(X, u, f)
        if frames.shape[0] > 0:  # out of the cell's frame: F^T f
            turn_rows(frames[e], f, True)
        if corotational:  # the force back in the global frame: R f_local
            f_local[:] = f
            for a in range(8):
                for i in range(3):
                    f[a, i] = (
                        R[i, 0] * f_local[a, 0] + R[i, 1] * f_local[a, 1] + R[i, 2] * f_local[a, 2]
                    )
        scatter_add_nodes(nodes, n_base, f, 1.0, f_base, f_extra)
    return energy


def ply_mean_strains(X: np.ndarray, u: np.ndarray, rule: PackedRule) -> np.ndarray:
    """(n_plies, 6) mean shell-frame strain of each ply of one undamaged (sub)element, as the
    damaged kernels sample it (its enhanced thickness strain condensed with the plies'
    stiffness; plain wrapper for tests and post-processing)."""
    n_plies = rule.stiffness.shape[0]
    strains = np.empty((n_plies, 6))
    _ply_mean_strains_one(
        np.ascontiguousarray(X, dtype=np.float64),
        np.ascontiguousarray(u, dtype=np.float64),
        *rule,
        strains,
        np.empty((n_plies, 3)),
    )
    return strains


@njit(cache=True, **KERNEL_OPTIONS)
def _ply_mean_strains_one(
    X,
    u,
    zeta,
    weights,
    terms,
    ply_of_point,
    position_of_point,
    positions,
    stiffness,
    enhanced_mode,
    strains,
    volumes,
):
    stop = weights.shape[0]
    maps = np.empty((N_MAPS, stop))
    work = np.empty((2, 8, 3))
    line = np.empty((4, 3, 3))
    _point_maps(X, u, 0, stop, zeta, weights, position_of_point, positions, work, line, maps)
    _condense_enhanced_strain(
        0,
        stop,
        weights,
        terms,
        ply_of_point,
        position_of_point,
        stiffness,
        enhanced_mode,
        None,
        None,
        maps,
    )
    _ply_means(0, stop, terms, ply_of_point, maps, strains, volumes)
