"""The elastic internal force of many solid-shell (sub)elements at once, vectorised across
elements that share a packed rule: the production kernel of every elastic solid element
(unrefined cells whole, subelements of refined ones, layerwise cells).

Units: N, mm, s, tonne (forces N, strain energy mJ).

Why a second loop structure. ``subelement.element_force_kernel`` takes one element at a time and
vectorises along a vertical line of points; a subelement of two plies has only three points per
line, shorter than one vector register, so that kernel runs at scalar speed. Here up to
``LANES`` elements with the same rule are taken together, one element per vector lane: every
point of the rule is one loop over the lanes, with the point's weight and stiffness the same for
all of them. The mathematics is ``element_force_kernel``'s (the same point helpers: inverse
Jacobian, strain, stress maps, first Piola-Kirchhoff stress; the same condensation of the
enhanced thickness strain line by line; the same monomial moments and butterflies), and
``tests/test_batched.py`` holds the two equal to round-off on distorted elements, small strain
and finite.

Stiffness. The rule's stiffnesses are read as symmetric (C[0, 1] for both C[0, 1] and C[1, 0],
and so on): ``pack_rule`` checks that they are, to 1e-12 of their largest entry, and the
one-element kernel reads the other triangle where it needs it, so the two agree to round-off.

Layout. Per-lane values live in flat arrays with the lane index last and a stride of the
compile-time constant ``LANES``: row r of lane w is ``a[r * LANES + w]``. With that constant
stride the compiler can prove that the rows written in one lane loop do not overlap, and each
lane loop is a plain vector loop; the per-point lane loops are separate (not inlined) functions
for the same reason: compiled alone, their loops vectorise, inlined into the driver they did not.

The driver ``add_subelement_forces`` walks the elements in ``order`` (elements grouped by rule,
``lane_order``) in runs of at most ``LANES`` elements with one rule; results do not depend on
the grouping beyond the order in which forces are summed at shared nodes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fenics_adaptive.element.assumed_strain import (
    DIRECTOR_TOLERANCE,
    corrected_strain,
    correction_forces,
    edge_sampled_strain,
    strain_coefficients,
    stress_on_director,
    work_weights,
)
from fenics_adaptive.element.subelement import (
    KERNEL_OPTIONS,
    TERM_NORMAL,
    TERM_SHEAR_CROSS,
    TERM_SHEAR_XZ,
    TERM_SHEAR_YZ,
    _first_piola,
    _inverse3,
    _line_end,
    _matmul3,
    _normal_stress_map,
    _shear_stress_map,
    _strain,
)

__all__ = ["LANES", "add_subelement_forces", "lane_order"]

# Elements per batch: twice the 8 doubles of a 512-bit register, so that the lane loops of a
# full batch run as whole vectors, and a run of fewer same-rule elements still fills some.
LANES = 16

# rows of the per-line accumulator ``acc`` (row r of lane w at acc[r * LANES + w]):
_M = 0  # 9 rows: sum over the line's points of P = w |det J| sigma J^-T (row-major)
_N = 9  # 6 rows: sum of zeta P, columns 0 and 1 (``subelement._add_point_moments``)
_MC = 15  # 9 + 6 rows: the same two moments of the enhanced mode's stress per unit alpha
_R = 30  # the enhanced strain's residual at alpha = 0
_H = 31  # its stiffness
_T = 32  # sum of w |det J| sigma : k k, the work-conjugate of the edge-sampled dE
_TC = 33  # its part per unit alpha
_E = 34  # strain energy of the element (not zeroed per line, nor are the rows below)
_DE = 35  # dE of the line (``assumed_strain``; zero in a lane whose directors are parallel)
_S = 36  # 5 rows: the cell's strain coefficients (``assumed_strain``), zero where not bent
_W = 41  # 6 rows: the cell's work weights
_BENT = 47  # 1.0 in a lane whose directors bend
_ROWS = 48


def lane_order(rule_of_element: np.ndarray) -> np.ndarray:
    """The elements grouped by rule (stable: each group keeps the elements' order): the order in
    which ``add_subelement_forces`` takes them, as int64."""
    return np.argsort(np.asarray(rule_of_element), kind="stable").astype(np.int64)


@njit(inline="always")
def _butterfly(values, transposed, nw):
    """The Moebius transform of ``values`` (8 vertices x 3 components x LANES) into monomial
    coefficients in place, or with ``transposed`` its transpose (monomial derivatives back to
    vertex forces); ``subelement._monomials`` and the end of ``element_force_kernel``."""
    for d in range(3):
        bit = 1 << d
        for m in range(8):
            if m & bit:
                for i in range(3):
                    low = ((m ^ bit) * 3 + i) * LANES
                    high = (m * 3 + i) * LANES
                    if transposed:
                        for w in range(nw):
                            values[low + w] -= values[high + w]
                    else:
                        for w in range(nw):
                            values[high + w] -= values[low + w]


@njit(cache=True)
def _gather_monomials(element_nodes, order, first, nw, n_base, base, extra, frames, out):
    """Monomial coefficients (``_butterfly``) of the vertex values of elements
    ``order[first:first + nw]``, lane by lane, from ``base`` / ``extra`` (n, 3) by combined local
    node index (``subelement.gather_nodes``); with ``frames`` (one 3 x 3 per element, rows its
    frame's axes; none: the global frame) the components in the element's frame, F v."""
    if frames.shape[0] == 0:  # the global frame: the plain copy (the flat meshes' hot path)
        for w in range(nw):
            nodes = element_nodes[order[first + w]]
            for a in range(8):
                node = nodes[a]
                for i in range(3):
                    if node < n_base:
                        out[(a * 3 + i) * LANES + w] = base[node, i]
                    else:
                        out[(a * 3 + i) * LANES + w] = extra[node - n_base, i]
    else:
        for w in range(nw):
            e = order[first + w]
            nodes = element_nodes[e]
            F = frames[e]
            for a in range(8):
                node = nodes[a]
                source = base if node < n_base else extra
                k = node if node < n_base else node - n_base
                v0, v1, v2 = source[k, 0], source[k, 1], source[k, 2]
                for i in range(3):
                    out[(a * 3 + i) * LANES + w] = F[i, 0] * v0 + F[i, 1] * v1 + F[i, 2] * v2
    _butterfly(out, False, nw)


@njit(cache=True)
def _scatter_forces(element_nodes, order, first, nw, n_base, forces, frames, base, extra):
    """Add the vertex forces of the lanes to ``base`` / ``extra`` (n, 3); with ``frames``
    (``_gather_monomials``) the forces are in the elements' frames: F^T f added."""
    if frames.shape[0] == 0:  # the global frame (the flat meshes' hot path)
        for w in range(nw):
            nodes = element_nodes[order[first + w]]
            for a in range(8):
                node = nodes[a]
                for i in range(3):
                    if node < n_base:
                        base[node, i] += forces[(a * 3 + i) * LANES + w]
                    else:
                        extra[node - n_base, i] += forces[(a * 3 + i) * LANES + w]
    else:
        for w in range(nw):
            e = order[first + w]
            nodes = element_nodes[e]
            F = frames[e]
            for a in range(8):
                node = nodes[a]
                f0 = forces[(a * 3) * LANES + w]
                f1 = forces[(a * 3 + 1) * LANES + w]
                f2 = forces[(a * 3 + 2) * LANES + w]
                target = base if node < n_base else extra
                k = node if node < n_base else node - n_base
                for i in range(3):
                    target[k, i] += F[0, i] * f0 + F[1, i] * f1 + F[2, i] * f2


@njit(cache=True, **KERNEL_OPTIONS)
def _fill_lines(bx, bu, xi, eta, line, nw):
    """``subelement._fill_line`` of every lane: on the vertical line (xi, eta), J = line[0] +
    zeta line[1] and G = line[2] + zeta line[3] (each 3 x 3 x LANES, row-major)."""
    for s in range(2):
        b = bx if s == 0 else bu
        for i in range(3):
            b1 = (3 + i) * LANES
            b2 = (6 + i) * LANES
            b3 = (9 + i) * LANES
            b4 = (12 + i) * LANES
            b5 = (15 + i) * LANES
            b6 = (18 + i) * LANES
            b7 = (21 + i) * LANES
            at = (2 * s * 9 + 3 * i) * LANES
            slope = ((2 * s + 1) * 9 + 3 * i) * LANES
            for w in range(nw):
                line[at + w] = b[b1 + w] + eta * b[b3 + w]
                line[slope + w] = b[b5 + w] + eta * b[b7 + w]
                line[at + LANES + w] = b[b2 + w] + xi * b[b3 + w]
                line[slope + LANES + w] = b[b6 + w] + xi * b[b7 + w]
                line[at + 2 * LANES + w] = (
                    b[b4 + w] + xi * b[b5 + w] + eta * (b[b6 + w] + xi * b[b7 + w])
                )
                line[slope + 2 * LANES + w] = 0.0


@njit(inline="always")
def _lane_matrix(line, s, z, w):
    """Row-major 9-tuple of matrix s (0: J, 2: G) of lane w at height z of the line."""
    at = s * 9 * LANES + w
    up = at + 9 * LANES
    return (
        line[at] + z * line[up],
        line[at + LANES] + z * line[up + LANES],
        line[at + 2 * LANES],
        line[at + 3 * LANES] + z * line[up + 3 * LANES],
        line[at + 4 * LANES] + z * line[up + 4 * LANES],
        line[at + 5 * LANES],
        line[at + 6 * LANES] + z * line[up + 6 * LANES],
        line[at + 7 * LANES] + z * line[up + 7 * LANES],
        line[at + 8 * LANES],
    )


@njit(inline="always")
def _add_moments(acc, row, P, z, w):
    """acc rows row:row + 9 += P, rows row + 9:row + 15 += zeta P[:, :2] (lane w)."""
    acc[row * LANES + w] += P[0]
    acc[(row + 1) * LANES + w] += P[1]
    acc[(row + 2) * LANES + w] += P[2]
    acc[(row + 3) * LANES + w] += P[3]
    acc[(row + 4) * LANES + w] += P[4]
    acc[(row + 5) * LANES + w] += P[5]
    acc[(row + 6) * LANES + w] += P[6]
    acc[(row + 7) * LANES + w] += P[7]
    acc[(row + 8) * LANES + w] += P[8]
    acc[(row + 9) * LANES + w] += z * P[0]
    acc[(row + 10) * LANES + w] += z * P[1]
    acc[(row + 11) * LANES + w] += z * P[3]
    acc[(row + 12) * LANES + w] += z * P[4]
    acc[(row + 13) * LANES + w] += z * P[6]
    acc[(row + 14) * LANES + w] += z * P[7]


@njit(inline="always")
def _normal_point_lanes(line, acc, z, weight, wg, C, finite, bent, nw):
    """One point of a "normal" line in every lane: its energy, its P moments and the enhanced
    strain's residual, stiffness and moments (``element_force_kernel``'s normal branch);
    ``bent``: with the edge-sampled thickness strain (rows _DE, _T, _TC)."""
    C00, C01, C02, C05, C11, C12, C15, C22, C25, C55 = C
    for w in range(nw):
        det, K = _inverse3(_lane_matrix(line, 0, z, w))
        H = _matmul3(_lane_matrix(line, 2, z, w), K)
        strain = _strain(H, finite)
        if bent:
            strain = corrected_strain(strain, acc[_DE * LANES + w], K)
        exx, eyy, ezz, _, _, gxy = strain
        wd = weight * abs(det)
        sxx = C00 * exx + C01 * eyy + C02 * ezz + C05 * gxy
        syy = C01 * exx + C11 * eyy + C12 * ezz + C15 * gxy
        szz = C02 * exx + C12 * eyy + C22 * ezz + C25 * gxy
        sxy = C05 * exx + C15 * eyy + C25 * ezz + C55 * gxy
        acc[_E * LANES + w] += 0.5 * wd * (sxx * exx + syy * eyy + szz * ezz + sxy * gxy)
        P = _normal_stress_map(wd * sxx, wd * syy, wd * szz, wd * sxy, K)
        _add_moments(acc, _M, _first_piola(P, H, finite), z, w)
        acc[_R * LANES + w] += wg * szz
        acc[_H * LANES + w] += wg * wg * C22 / wd
        Pc = _normal_stress_map(wg * C02, wg * C12, wg * C22, wg * C25, K)
        _add_moments(acc, _MC, _first_piola(Pc, H, finite), z, w)
        if bent:
            acc[_T * LANES + w] += stress_on_director(P, K)
            acc[_TC * LANES + w] += stress_on_director(Pc, K)


@njit(cache=True, **KERNEL_OPTIONS)
def _normal_points(line, acc, z, weight, wg, C, finite, bent, nw):
    """``_normal_point_lanes`` with ``finite`` and ``bent`` made constants (one vector loop
    each)."""
    if finite:
        if bent:
            _normal_point_lanes(line, acc, z, weight, wg, C, True, True, nw)
        else:
            _normal_point_lanes(line, acc, z, weight, wg, C, True, False, nw)
    elif bent:
        _normal_point_lanes(line, acc, z, weight, wg, C, False, True, nw)
    else:
        _normal_point_lanes(line, acc, z, weight, wg, C, False, False, nw)


@njit(inline="always")
def _shear_point_lanes(line, acc, z, weight, c_xz, c_yz, c_cross, finite, bent, nw):
    """One point of a transverse shear line in every lane (``element_force_kernel``)."""
    for w in range(nw):
        det, K = _inverse3(_lane_matrix(line, 0, z, w))
        H = _matmul3(_lane_matrix(line, 2, z, w), K)
        strain = _strain(H, finite)
        if bent:
            strain = corrected_strain(strain, acc[_DE * LANES + w], K)
        _, _, _, gyz, gxz, _ = strain
        wd = weight * abs(det)
        sxz = c_xz * gxz + c_cross * gyz
        syz = c_yz * gyz + c_cross * gxz
        acc[_E * LANES + w] += 0.5 * wd * (sxz * gxz + syz * gyz)
        P = _shear_stress_map(wd * syz, wd * sxz, K)
        _add_moments(acc, _M, _first_piola(P, H, finite), z, w)
        if bent:
            acc[_T * LANES + w] += stress_on_director(P, K)


@njit(cache=True, **KERNEL_OPTIONS)
def _shear_points(line, acc, z, weight, c_xz, c_yz, c_cross, finite, bent, nw):
    """``_shear_point_lanes`` with ``finite`` and ``bent`` made constants."""
    if finite:
        if bent:
            _shear_point_lanes(line, acc, z, weight, c_xz, c_yz, c_cross, True, True, nw)
        else:
            _shear_point_lanes(line, acc, z, weight, c_xz, c_yz, c_cross, True, False, nw)
    elif bent:
        _shear_point_lanes(line, acc, z, weight, c_xz, c_yz, c_cross, False, True, nw)
    else:
        _shear_point_lanes(line, acc, z, weight, c_xz, c_yz, c_cross, False, False, nw)


@njit(cache=True, **KERNEL_OPTIONS)
def _bent_lanes(bx, bu, acc, finite, nw):
    """Mark the lanes whose directors bend (row _BENT; ``assumed_strain.directors_bend``), set
    their strain coefficients (rows _S, zero in the other lanes) and zero their work weights;
    returns whether any lane bends."""
    any_bent = False
    half = 0.5 if finite else 0.0
    for w in range(nw):
        bend = 0.0
        size = 0.0
        for i in range(3):
            for m in (5, 6, 7):
                value = bx[(m * 3 + i) * LANES + w]
                bend += value * value
            size += bx[(12 + i) * LANES + w] * bx[(12 + i) * LANES + w]
        bent = bend > DIRECTOR_TOLERANCE * DIRECTOR_TOLERANCE * size
        acc[_BENT * LANES + w] = 1.0 if bent else 0.0
        any_bent = any_bent or bent
        for c in range(5):
            acc[(_S + c) * LANES + w] = 0.0
        for c in range(6):
            acc[(_W + c) * LANES + w] = 0.0
        if bent:
            for i in range(3):
                b5 = bu[(15 + i) * LANES + w]
                b6 = bu[(18 + i) * LANES + w]
                b7 = bu[(21 + i) * LANES + w]
                c = strain_coefficients(
                    bx[(15 + i) * LANES + w] + half * b5,
                    bx[(18 + i) * LANES + w] + half * b6,
                    bx[(21 + i) * LANES + w] + half * b7,
                    b5,
                    b6,
                    b7,
                )
                for k in range(5):
                    acc[(_S + k) * LANES + w] += c[k]
    return any_bent


@njit(cache=True, **KERNEL_OPTIONS)
def _line_strains(acc, xi, eta, nw):
    """dE of the line (xi, eta) in every lane (row _DE) from the strain coefficients."""
    for w in range(nw):
        acc[_DE * LANES + w] = edge_sampled_strain(
            acc[_S * LANES + w],
            acc[(_S + 1) * LANES + w],
            acc[(_S + 2) * LANES + w],
            acc[(_S + 3) * LANES + w],
            acc[(_S + 4) * LANES + w],
            xi,
            eta,
        )


@njit(cache=True, **KERNEL_OPTIONS)
def _line_weights(acc, xi, eta, nw):
    """Add the line's work weights (its T, row _T) to the cell's (rows _W), in the lanes whose
    directors bend (in the others T is the stress's work on a dE that is not there)."""
    for w in range(nw):
        weights = work_weights(acc[_T * LANES + w] * acc[_BENT * LANES + w], xi, eta)
        for c in range(6):
            acc[(_W + c) * LANES + w] += weights[c]


@njit(cache=True, **KERNEL_OPTIONS)
def _add_correction_forces(bx, bu, acc, forces, finite, nw):
    """The cells' forces through dE into the monomial derivatives ``forces``
    (``assumed_strain.correction_forces``; the current director under finite strain)."""
    full = 1.0 if finite else 0.0
    for i in range(3):
        for w in range(nw):
            W = (
                acc[_W * LANES + w],
                acc[(_W + 1) * LANES + w],
                acc[(_W + 2) * LANES + w],
                acc[(_W + 3) * LANES + w],
                acc[(_W + 4) * LANES + w],
                acc[(_W + 5) * LANES + w],
            )
            f5, f6, f7 = correction_forces(
                bx[(15 + i) * LANES + w] + full * bu[(15 + i) * LANES + w],
                bx[(18 + i) * LANES + w] + full * bu[(18 + i) * LANES + w],
                bx[(21 + i) * LANES + w] + full * bu[(21 + i) * LANES + w],
                W,
            )
            forces[(15 + i) * LANES + w] += f5
            forces[(18 + i) * LANES + w] += f6
            forces[(21 + i) * LANES + w] += f7


@njit(cache=True, **KERNEL_OPTIONS)
def _condense(acc, nw):
    """Condense each lane's enhanced thickness strain of the line: alpha = -r / h (where h > 0)
    adds alpha times its moments and -1/2 r^2 / h to the energy."""
    for w in range(nw):
        h = acc[_H * LANES + w]
        if h > 0.0:
            r = acc[_R * LANES + w]
            alpha = -r / h
            acc[_E * LANES + w] -= 0.5 * r * r / h
            for c in range(15):
                acc[(_M + c) * LANES + w] += alpha * acc[(_MC + c) * LANES + w]
            acc[_T * LANES + w] += alpha * acc[_TC * LANES + w]


@njit(cache=True, **KERNEL_OPTIONS)
def _add_line_moments(acc, forces, xi, eta, nw):
    """``subelement._add_line_moments`` of every lane: the line's moments into the derivatives
    with respect to the monomial coefficients (``forces``, 8 x 3 x LANES)."""
    for i in range(3):
        m0x = (_M + 3 * i) * LANES
        m0y = m0x + LANES
        m0z = m0x + 2 * LANES
        m1x = (_N + 2 * i) * LANES
        m1y = m1x + LANES
        for w in range(nw):
            forces[(3 + i) * LANES + w] += acc[m0x + w]
            forces[(6 + i) * LANES + w] += acc[m0y + w]
            forces[(9 + i) * LANES + w] += eta * acc[m0x + w] + xi * acc[m0y + w]
            forces[(12 + i) * LANES + w] += acc[m0z + w]
            forces[(15 + i) * LANES + w] += acc[m1x + w] + xi * acc[m0z + w]
            forces[(18 + i) * LANES + w] += acc[m1y + w] + eta * acc[m0z + w]
            forces[(21 + i) * LANES + w] += (
                eta * acc[m1x + w] + xi * acc[m1y + w] + xi * eta * acc[m0z + w]
            )


@njit(cache=True, **KERNEL_OPTIONS)
def _vertex_forces(forces, nw):
    """Monomial derivatives (8 x 3 x LANES) back to vertex forces in place (the transposed
    butterfly), compiled alone so that its lane loops vectorise."""
    _butterfly(forces, True, nw)


@njit(cache=True, **KERNEL_OPTIONS)
def add_subelement_forces(
    element_nodes,
    order,
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
    X_base,
    X_extra,
    u_base,
    u_extra,
    f_base,
    f_extra,
    finite,
    frames,
):
    """Add the elastic internal forces (N) of the elements ``element_nodes`` (n, 8) (combined
    local node indices, ``subelement.gather_nodes``) into ``f_base`` / ``f_extra`` (n, 3) from
    the reference positions ``X_*`` and displacements ``u_*`` (mm); returns their strain energy
    (mJ). ``frames`` (n, 3, 3): each element's frame (a curved shell's cells,
    ``element.geometry.cell_frames``), in which its strains are taken; (0, 3, 3): the global
    frame. Element e uses rule ``rule_of_element[e]`` of the packed rules that follow
    (``subelement.PackedRules``); ``order`` is ``lane_order(rule_of_element)``. ``finite``: total
    Lagrangian kinematics (a bool every time)."""
    n_base = X_base.shape[0]
    bx = np.empty(24 * LANES)
    bu = np.empty(24 * LANES)
    line = np.empty(36 * LANES)
    acc = np.empty(_ROWS * LANES)
    forces = np.empty(24 * LANES)
    energy = 0.0
    n = len(order)
    first = 0
    while first < n:
        rule = rule_of_element[order[first]]
        nw = 1
        while nw < LANES and first + nw < n and rule_of_element[order[first + nw]] == rule:
            nw += 1
        _gather_monomials(element_nodes, order, first, nw, n_base, X_base, X_extra, frames, bx)
        _gather_monomials(element_nodes, order, first, nw, n_base, u_base, u_extra, frames, bu)
        forces[:] = 0.0
        acc[_E * LANES :] = 0.0
        bent = _bent_lanes(bx, bu, acc, finite, nw)
        p = rule_offsets[rule]
        stop = rule_offsets[rule + 1]
        while p < stop:
            end = _line_end(position_of_point, p, stop)
            q = position_of_point[p]
            xi = positions[q, 0]
            eta = positions[q, 1]
            _fill_lines(bx, bu, xi, eta, line, nw)
            acc[: _E * LANES] = 0.0
            if bent:
                _line_strains(acc, xi, eta, nw)
            term = terms[p]
            for pp in range(p, end):
                k = ply_of_point[pp]
                if term == TERM_NORMAL:
                    C = (
                        stiffness[k, 0, 0],
                        stiffness[k, 0, 1],
                        stiffness[k, 0, 2],
                        stiffness[k, 0, 5],
                        stiffness[k, 1, 1],
                        stiffness[k, 1, 2],
                        stiffness[k, 1, 5],
                        stiffness[k, 2, 2],
                        stiffness[k, 2, 5],
                        stiffness[k, 5, 5],
                    )
                    wg = weights[pp] * enhanced_mode[pp]
                    _normal_points(line, acc, zeta[pp], weights[pp], wg, C, finite, bent, nw)
                else:
                    c_xz = stiffness[k, 4, 4] if term == TERM_SHEAR_XZ else 0.0
                    c_yz = stiffness[k, 3, 3] if term == TERM_SHEAR_YZ else 0.0
                    c_cross = stiffness[k, 3, 4] if term == TERM_SHEAR_CROSS else 0.0
                    _shear_points(
                        line, acc, zeta[pp], weights[pp], c_xz, c_yz, c_cross, finite, bent, nw
                    )
            if term == TERM_NORMAL:
                _condense(acc, nw)
            _add_line_moments(acc, forces, xi, eta, nw)
            if bent:
                _line_weights(acc, xi, eta, nw)
            p = end
        if bent:
            _add_correction_forces(bx, bu, acc, forces, finite, nw)
        _vertex_forces(forces, nw)
        _scatter_forces(element_nodes, order, first, nw, n_base, forces, frames, f_base, f_extra)
        for w in range(nw):
            energy += acc[_E * LANES + w]
        first += nw
    return energy
