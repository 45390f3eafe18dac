"""The stresses and strains the indicators read at every ply of every cell: at the ply's
mid-thickness, at the in-plane centre of its cell, from whichever element holds the ply (the
whole cell, a subelement of a refined cell, or a layerwise cell), with the element's enhanced
thickness strain and its transverse shear correction (paper, "Adaptivity").

Units: N, mm, s, tonne (stresses MPa).

``ElementData`` keeps what the element loop reads until the structure refines (the elements,
the maps from their displacements to their enhanced strain parameter, the plies' shear scale
and stiffness); a refinement keeps the maps of the elements it did not change.
"""

from __future__ import annotations

import itertools
import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from fenics_adaptive.element.assumed_strain import (
    cell_strain_coefficients,
    directors_bend,
    edge_sampled_strain,
)
from fenics_adaptive.element.solid_shell import NORMAL  # a monoclinic ply couples these
from fenics_adaptive.element.subelement import (
    _monomials,
    element_rotation,
    gather_nodes,
    to_rotated_frame,
    turn_rows,
)
from fenics_adaptive.materials.laminate import rotation_about_z
from fenics_adaptive.materials.ply_damage import S_FT, S_MC, hashin_indices


@njit(cache=True)
def _inverse_3x3(A, out):
    """out = A^-1 (3 x 3, by cofactors and one reciprocal); returns det A."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    r = 1.0 / det
    out[0, 0] = c00 * r
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * r
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * r
    out[1, 0] = c01 * r
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * r
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * r
    out[2, 0] = c02 * r
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * r
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * r
    return det


# what ``_ply_kernel`` makes of the strain at each ply's centre
STRAINS, STRESSES, SUMS = 0, 1, 2
# an element is a prism when its top face's edges equal its bottom face's to this share of its
# size: a mesh's coordinates, computed apart for the two faces, differ in the last bits
PRISM_TOLERANCE = 1.0e-12


# the columns of ``_element_geometry``'s rows: J^-1 (row by row), |det J|, prism, bends
G_DET, G_PRISM, G_BENDS = 9, 10, 11
GEOMETRY_WIDTH = 12


@njit(cache=True)
def _axis_parts(values, out):
    """out (3, 5): the derivatives of the trilinear interpolant of ``values`` (8, 3) on the
    element's axis, per component: d/d xi on the bottom and top faces, d/d eta on the bottom
    and top faces, d/d zeta (which does not vary along the axis)."""
    out[:] = 0.0
    for a in range(8):
        s_xi = 0.5 if a & 1 else -0.5
        s_eta = 0.5 if (a >> 1) & 1 else -0.5
        top = (a >> 2) & 1
        s_zeta = 0.25 if top else -0.25
        for i in range(3):
            value = values[a, i]
            out[i, top] += s_xi * value
            out[i, 2 + top] += s_eta * value
            out[i, 4] += s_zeta * value


@njit(cache=True)
def _prism_inverse(parts, J, Jinv):
    """det J, and J (3 x 3) and J^-1 into ``J``, ``Jinv``, of an element whose coordinates'
    ``_axis_parts`` are ``parts``, if it is a prism (its top face's edges equal its bottom
    face's to ``PRISM_TOLERANCE`` of its size, the round-off of a mesh's coordinates); 0.0
    (and J, Jinv untouched) otherwise."""
    size = 0.0
    for i in range(3):
        size = max(size, abs(parts[i, 0]) + abs(parts[i, 2]) + abs(parts[i, 4]))
    for i in range(3):
        if (
            abs(parts[i, 0] - parts[i, 1]) > PRISM_TOLERANCE * size
            or abs(parts[i, 2] - parts[i, 3]) > PRISM_TOLERANCE * size
        ):
            return 0.0
    for i in range(3):
        J[i, 0] = parts[i, 0]
        J[i, 1] = parts[i, 2]
        J[i, 2] = parts[i, 4]
    return _inverse_3x3(J, Jinv)


@njit(cache=True)
def _element_geometry(X, geometry):
    """geometry[e] (n, ``GEOMETRY_WIDTH``): what ``_ply_kernel`` reads of the shape of each
    element with vertices X[e] (n, 8, 3; on a curved shell in the element's frame): J^-1 on
    its axis and |det J| if it is a prism (``_prism_inverse``), whether it is one, whether
    its directors bend (``assumed_strain.directors_bend``)."""
    b = np.empty((8, 3))
    parts = np.empty((3, 5))
    J, Jinv = np.empty((3, 3)), np.empty((3, 3))
    for e in range(X.shape[0]):
        _axis_parts(X[e], parts)
        det = _prism_inverse(parts, J, Jinv)
        geometry[e, :] = 0.0
        if det != 0.0:
            for i in range(3):
                for r in range(3):
                    geometry[e, 3 * i + r] = Jinv[i, r]
            geometry[e, G_DET] = abs(det)
            geometry[e, G_PRISM] = 1.0
        _monomials(X[e], b)
        geometry[e, G_BENDS] = 1.0 if directors_bend(b) else 0.0


@njit(cache=True)
def _ply_kernel(
    X_base,
    X_extra,
    u_base,
    u_extra,
    nodes,
    cells,
    plies,
    fractions,
    centre_maps,
    root,
    corotational,
    frames,
    geometry,
    mode,
    stiffness,
    out,
    pattern,
    of_pattern,
    of_ply,
    kinds,
    per_ply,
    sums,
):
    """The small strain (Voigt, engineering shears) at the in-plane centre of every ply of every
    element, at the ply's mid-thickness, with the element's enhanced thickness strain
    alpha g(zeta) / |det J| (alpha its parameter at the in-plane centre, the map
    ``centre_maps[e]`` (``ElementData.centre_maps``) of its nodes' displacements) and, where
    its directors bend, its edge-sampled thickness strain (``element.assumed_strain``), and
    what ``mode`` makes of it:

    - ``STRAINS``: the strain into out[cell, ply];
    - ``STRESSES``: the ply's stress C_k (D strain) into out[cell, ply] (``stiffness``
      (n_plies, 6, 6), monoclinic; D the shear scale of the ply in its element, ``root``
      (n_patterns, n_plies, 2) sqrt m_xz, sqrt m_yz of each ply in each element's ply range
      ``pattern[e]`` (``materials.laminate.ply_shear_factors``): ``ply_stresses``);
    - ``SUMS``: sums[cell, r] += sum_k w_rk sigma_k[i_r] over the element's plies
      (``PlySums``). Along the axis of a prism the strain is linear in zeta, eps = (1 - zeta)
      eps_bottom + zeta eps_top, so each row is fixed coefficients of the element's ply range
      (``of_pattern[pattern[e]]``, ``_sum_matrices``) on the strain at its bottom and top,
      zeta = 0 and 1; otherwise (or with ``per_ply``) of each ply (``of_ply[k]``) on that
      ply's strain. A normal stress row (``kinds[r]`` 0) reads the normal strains; a
      transverse shear row (3: tau_yz, 4: tau_xz) gamma_yz and gamma_xz apart, scaled by the
      ply's shear factors in the element (``_scaled``; a force row, ``PlySums.forces``,
      once more).

    ``corotational`` (finite kinematics): in the element's co-rotated frame, as the damaged
    kernel computes it (``subelement.element_rotation``): the displacement there, and alpha
    from it. ``frames`` (n_elements, 3, 3): on a curved shell, each element's frame, in which
    its strain is taken (``subelement.add_damaged_subelement_forces``); (0, 3, 3): the global
    frame. ``geometry`` (n_elements, ``GEOMETRY_WIDTH``): what each element's shape alone decides
    (``_element_geometry``), which only the co-rotated frame changes; (0, ``GEOMETRY_WIDTH``):
    formed here from the coordinates (the co-rotated frame's).

    On the element's axis (xi = eta = 1/2) the trilinear shape functions' in-plane derivatives
    are (1 - zeta) times the bottom face's plus zeta times the top face's, and the thickness
    derivative does not depend on zeta: the Jacobian and the displacement gradient (in the
    element's coordinates) are formed once per element, as a bottom, a top and a normal part,
    and combined per ply. (One kernel for the three: a call per ply to a shared helper cost
    more than the ply's arithmetic.)"""
    n_base = X_base.shape[0]
    X, u, u_global = np.empty((8, 3)), np.empty((8, 3)), np.empty((8, 3))
    monomials = np.empty((2, 8, 3))
    parts = np.zeros((2, 3, 5))  # (X, u), component, (d_xi bottom, top, d_eta bottom, top, d_zeta)
    J, G, Jinv, grad = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    ends = np.empty((2, 3, 3))
    strain = np.empty(6)
    # a prism's normal strains at its bottom and top, then gamma_yz, gamma_xz there (``SUMS``)
    both = np.empty(12)
    R = np.eye(3)
    n_rows = kinds.shape[0]
    known = geometry.shape[0] > 0
    for e in range(nodes.shape[0]):
        # a prism without bent directors needs its coordinates only for what ``geometry`` holds
        prism = known and geometry[e, G_PRISM] != 0.0
        bends = known and geometry[e, G_BENDS] != 0.0
        coordinates = not prism or bends
        if coordinates:
            gather_nodes(nodes[e], n_base, X_base, X_extra, X)
        if corotational:
            gather_nodes(nodes[e], n_base, u_base, u_extra, u_global)
            element_rotation(X, u_global, R)
            to_rotated_frame(X, u_global, R, u)
        else:
            gather_nodes(nodes[e], n_base, u_base, u_extra, u)
        if frames.shape[0] > 0:
            if coordinates:
                turn_rows(frames[e], X, False)
            turn_rows(frames[e], u, False)
        alpha = 0.0
        for a in range(8):
            for i in range(3):
                alpha += centre_maps[e, a, i] * u[a, i]
        sampled = 0.0  # the edge-sampled thickness strain on the axis, where the directors bend
        if coordinates:
            if bends or not known:  # (``geometry`` says whether they bend)
                _monomials(X, monomials[0])
                if bends or directors_bend(monomials[0]):
                    _monomials(u, monomials[1])
                    s55, s57, s77, s66, s67 = cell_strain_coefficients(
                        monomials[0], monomials[1], False
                    )
                    sampled = edge_sampled_strain(s55, s57, s77, s66, s67, 0.5, 0.5)
            _axis_parts(X, parts[0])
        _axis_parts(u, parts[1])
        first, stop = plies[e, 0], plies[e, 1]
        bottom, top_f = fractions[first], fractions[stop]
        # a prism (top face a translate of the bottom one): J does not vary along the axis,
        # and grad u = G J^-1 is linear in zeta there: two products per element
        enhanced = 0.0  # alpha / |det J| of the element (a prism) or of the ply
        if known:
            if prism:
                for i in range(3):
                    for r in range(3):
                        Jinv[i, r] = geometry[e, 3 * i + r]
                enhanced = alpha / geometry[e, G_DET]
        else:
            det = _prism_inverse(parts[0], J, Jinv)
            prism = det != 0.0
            if prism:
                enhanced = alpha / abs(det)
        if prism:
            for f in range(2):  # grad u on the bottom (0) and top (1) face
                for i in range(3):
                    g0, g1, g2 = parts[1, i, f], parts[1, i, 2 + f], parts[1, i, 4]
                    for r in range(3):
                        ends[f, i, r] = g0 * Jinv[0, r] + g1 * Jinv[1, r] + g2 * Jinv[2, r]
        ends_only = mode == SUMS and prism and not per_ply  # the strain at zeta = 0 and 1
        span = 1.0 / (top_f - bottom)
        c = cells[e]
        p = pattern[e]
        points = 2 if ends_only else stop - first
        for point in range(points):
            k = first + point
            if ends_only:
                zeta = float(point)
            else:
                zeta = (0.5 * (fractions[k] + fractions[k + 1]) - bottom) * span
            if prism:
                for i in range(3):
                    for r in range(3):
                        grad[i, r] = (1.0 - zeta) * ends[0, i, r] + zeta * ends[1, i, r]
            else:
                for i in range(3):
                    J[i, 0] = (1.0 - zeta) * parts[0, i, 0] + zeta * parts[0, i, 1]
                    J[i, 1] = (1.0 - zeta) * parts[0, i, 2] + zeta * parts[0, i, 3]
                    J[i, 2] = parts[0, i, 4]
                    G[i, 0] = (1.0 - zeta) * parts[1, i, 0] + zeta * parts[1, i, 1]
                    G[i, 1] = (1.0 - zeta) * parts[1, i, 2] + zeta * parts[1, i, 3]
                    G[i, 2] = parts[1, i, 4]
                enhanced = alpha / abs(_inverse_3x3(J, Jinv))
                for i in range(3):
                    for r in range(3):
                        grad[i, r] = (
                            G[i, 0] * Jinv[0, r] + G[i, 1] * Jinv[1, r] + G[i, 2] * Jinv[2, r]
                        )
            strain[0] = grad[0, 0]
            strain[1] = grad[1, 1]
            strain[2] = grad[2, 2] + enhanced * (zeta - 0.5)
            strain[3] = grad[1, 2] + grad[2, 1]
            strain[4] = grad[0, 2] + grad[2, 0]
            strain[5] = grad[0, 1] + grad[1, 0]
            if sampled != 0.0:  # bent directors; Jinv is this point's (or, a prism's, the same)
                k0, k1, k2 = Jinv[2, 0], Jinv[2, 1], Jinv[2, 2]
                strain[0] += sampled * k0 * k0
                strain[1] += sampled * k1 * k1
                strain[2] += sampled * k2 * k2
                strain[3] += 2.0 * sampled * k1 * k2
                strain[4] += 2.0 * sampled * k0 * k2
                strain[5] += 2.0 * sampled * k0 * k1
            if ends_only:  # (normal strains, then the shears, as the rows take them)
                for q in range(4):
                    both[4 * point + q] = strain[NORMAL[q]]
                both[8 + point] = strain[3]
                both[10 + point] = strain[4]
            elif mode == SUMS:
                for r in range(n_rows):
                    if kinds[r] == 0:
                        total = 0.0
                        for q in range(4):
                            total += of_ply[k, r, q] * strain[NORMAL[q]]
                        sums[c, r] += total
                    else:
                        a = of_ply[k, r, 0] * strain[3]
                        b = of_ply[k, r, 1] * strain[4]
                        sums[c, r] += _scaled(kinds[r], root[p, k, 0], root[p, k, 1], a, b)
            elif mode == STRESSES:  # monoclinic plies: the normal and transverse shear parts
                for a in range(4):
                    i = NORMAL[a]
                    total = 0.0
                    for b in range(4):
                        total += stiffness[k, i, NORMAL[b]] * strain[NORMAL[b]]
                    out[c, k, i] = total
                for i in (3, 4):  # C_k (D strain) of the transverse shears
                    a = stiffness[k, i, 3] * strain[3]
                    b = stiffness[k, i, 4] * strain[4]
                    out[c, k, i] = _scaled(i, root[p, k, 0], root[p, k, 1], a, b)
            else:
                for i in range(6):
                    out[c, k, i] = strain[i]
        if ends_only:
            for r in range(n_rows):
                if kinds[r] == 0:
                    total = 0.0
                    for q in range(8):
                        total += of_pattern[p, r, q] * both[q]
                    sums[c, r] += total
                else:
                    a = of_pattern[p, r, 0] * both[8] + of_pattern[p, r, 1] * both[9]
                    b = of_pattern[p, r, 2] * both[10] + of_pattern[p, r, 3] * both[11]
                    sums[c, r] += a + b  # (the plies' shear scales are in the coefficients)


# a transverse shear row of ``PlySums.forces``: its kind is the component plus this
FORCE_ROW = 10


@njit(cache=True)
def _scaled(kind, root_xz, root_yz, a, b):
    """A transverse shear's two parts a = C[i, 3] gamma_yz, b = C[i, 4] gamma_xz (or a
    ``PlySums`` row's) with the ply's shear scales, C (D strain): r_yz a + r_xz b for
    tau_yz (``kind`` 3) and tau_xz (4); D C (D strain) for a force row (``FORCE_ROW`` + 3,
    + 4: times r_yz, r_xz once more); a alone for a normal stress."""
    if kind == 3 or kind == 4:
        return root_yz * a + root_xz * b
    if kind == 3 + FORCE_ROW:
        return root_yz * (root_yz * a + root_xz * b)
    if kind == 4 + FORCE_ROW:
        return root_xz * (root_yz * a + root_xz * b)
    return a


@njit(cache=True)
def _shear_scale(cells, plies, pattern, root, scale):
    """scale[cell, ply, 3 (yz), 4 (xz)] = root[p, ply, 1], root[p, ply, 0] for the plies
    [first, stop) of every element e of ply range p = ``pattern[e]`` (``ply_shear_scale``);
    the rest of ``scale`` untouched."""
    for e in range(cells.shape[0]):
        p = pattern[e]
        for ply in range(plies[e, 0], plies[e, 1]):
            scale[cells[e], ply, 3] = root[p, ply, 1]
            scale[cells[e], ply, 4] = root[p, ply, 0]


@dataclass
class ElementData:
    """What the ply strains and stresses read of the structure's solid elements, which change
    only when it refines: the elements (``Structure.elements``), the map from each one's
    nodal displacements (8, 3) to its enhanced thickness strain parameter at the in-plane
    centre (the mean of its four lines' small-strain maps, undamaged:
    ``RuleTable.enhanced_parameter_maps``), the square roots of its plies' shear factors, the
    plies' stiffnesses, where each (cell, interface) keeps its cohesive damage, and the distinct
    ply ranges of the elements (``ply_sums`` makes a matrix per range).
    ``subelements``: the structure's ``SubelementSet`` they were made for (a refinement makes
    a new one); ``keys``: each element's (cell, first ply, stop ply) as one integer, by which a
    refinement keeps the maps of the elements it did not change."""

    subelements: object
    nodes: np.ndarray
    cells: np.ndarray
    plies: np.ndarray
    keys: np.ndarray
    centre_maps: np.ndarray  # (n_elements, 8, 3) mm^3 / mm
    # (n_patterns, n_plies, 2) sqrt m_xz, sqrt m_yz of each ply in each ply range
    shear_roots: np.ndarray
    stiffness: np.ndarray  # (n_plies, 6, 6) MPa, shell frame
    cohesive_rows: np.ndarray  # (m, 3) cell, interface, damage row (``Structure.damage_rows``)
    fractions: np.ndarray  # (n_plies + 1,) the ply boundaries' height in the laminate, 0 to 1
    frames: np.ndarray  # (n_elements, 3, 3) on a curved shell, (0, 3, 3) flat (``element_frames``)
    geometry: np.ndarray  # (n_elements, GEOMETRY_WIDTH) ``_element_geometry``
    patterns: np.ndarray  # (n_patterns, 2) the distinct (first ply, stop ply) of the elements
    pattern: np.ndarray  # (n_elements,) each element's row of ``patterns``
    # ``ply_sums``' matrices by ``PlySums.key``, for these elements' patterns
    sum_matrices: dict = field(default_factory=dict)
    # the same per (key, first, stop) and per key (of_ply, kinds): kept when the structure
    # refines (``_sum_matrices``)
    range_matrices: dict = field(default_factory=dict)

    @classmethod
    def of(cls, structure, previous: ElementData | None = None) -> ElementData:
        """The structure's element data now. ``previous``: the same structure's before it
        refined, whose elements' maps (the same cell and plies: the same nodes and rule),
        cohesive rows and ply stiffnesses are kept."""
        nodes, cells, plies = structure.elements()
        table = structure.rule_table
        n_plies = structure.laminate.n_plies
        keys = (cells * (n_plies + 1) + plies[:, 0]) * (n_plies + 1) + plies[:, 1]
        centre_maps = np.empty((len(nodes), 8, 3))
        geometry = np.empty((len(nodes), GEOMETRY_WIDTH))
        todo = np.ones(len(nodes), dtype=bool)
        if previous is not None and len(previous.keys):
            order = np.argsort(previous.keys)
            at = np.minimum(np.searchsorted(previous.keys, keys, sorter=order), len(order) - 1)
            todo = previous.keys[order[at]] != keys
            centre_maps[~todo] = previous.centre_maps[order[at[~todo]]]
            geometry[~todo] = previous.geometry[order[at[~todo]]]
        frames = structure.base.element_frames(cells)
        X = structure.gather(nodes[todo], "X")
        if len(frames):  # the maps and shapes in each element's frame
            X = np.einsum("eij,eaj->eai", frames[todo], X)
        kept = np.empty((len(X), GEOMETRY_WIDTH))
        _element_geometry(np.ascontiguousarray(X), kept)
        geometry[todo] = kept
        maps = table.enhanced_parameter_maps(X, plies[todo])
        centre_maps[todo] = maps.mean(axis=1)
        if previous is None:
            stiffness = np.array(structure.laminate.ply_stiffnesses()).reshape(n_plies, 6, 6)
        else:
            stiffness = previous.stiffness
        # the distinct ply ranges, by (first, stop), through a table of every possible one
        codes = plies[:, 0] * (n_plies + 1) + plies[:, 1]
        present = np.zeros((n_plies + 1) ** 2, dtype=bool)
        present[codes] = True
        ranges = np.flatnonzero(present)
        place = np.zeros(len(present), dtype=np.int64)
        place[ranges] = np.arange(len(ranges))
        pattern = place[codes]
        patterns = np.column_stack(np.divmod(ranges, n_plies + 1))
        return cls(
            structure.refined_cells.subelements,
            nodes,
            cells,
            plies,
            keys,
            centre_maps,
            _shear_roots(table, patterns.reshape(-1, 2), n_plies),
            stiffness,
            _cohesive_rows(
                structure.damage_rows,
                None if previous is None else previous.cohesive_rows,
            ),
            np.asarray(structure.laminate.ply_fractions, dtype=float),
            frames,
            geometry,
            patterns.reshape(-1, 2).astype(np.int64),
            pattern.reshape(-1).astype(np.int64),
            range_matrices={} if previous is None else previous.range_matrices,
        )


def _cohesive_rows(damage_rows: dict, known: np.ndarray | None) -> np.ndarray:
    """(m, 3) the cell, interface and damage row of every pair of ``damage_rows``
    (``Structure.damage_rows``, whose pairs only ever come in at the end, each with its place
    as its row: ``RefinementState.mark_strong``); ``known``: this for the same dict before,
    whose rows are kept."""
    if known is None or len(known) > len(damage_rows):
        known = np.zeros((0, 3), np.int64)
    start, stop = len(known), len(damage_rows)
    if stop > start and next(reversed(damage_rows.values())) != stop - 1:
        raise RuntimeError("Structure.damage_rows: a pair's row is no longer its place")
    pairs = itertools.chain.from_iterable(itertools.islice(damage_rows, start, None))
    new = np.fromiter(pairs, np.int64, count=2 * (stop - start)).reshape(-1, 2)
    return np.vstack([known, np.column_stack([new, np.arange(start, stop, dtype=np.int64)])])


def _shear_roots(table, patterns: np.ndarray, n_plies: int) -> np.ndarray:
    """(n_patterns, n_plies, 2) sqrt m_xz, sqrt m_yz of each ply in the rule of each ply range
    (first, stop) of ``patterns`` (``RuleTable.ply_shear_factors``; 1 outside the range)."""
    roots = np.ones((len(patterns), n_plies, 2))
    for p, (first, stop) in enumerate(patterns.tolist()):
        roots[p, first:stop] = np.sqrt(table.ply_shear_factors(first, stop))
    return roots


# per structure (weakly held): its ElementData until it refines
_ELEMENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def element_data(structure) -> ElementData:
    """The structure's ``ElementData``, made again after it refined."""
    data = _ELEMENTS.get(structure)
    if data is None or data.subelements is not structure.refined_cells.subelements:
        data = _ELEMENTS[structure] = ElementData.of(structure, data)
    return data


_NO_GEOMETRY = np.zeros((0, GEOMETRY_WIDTH))


def _run_kernel(structure, mode: int, out=None, sums_args=None) -> None:
    """``_ply_kernel`` on the structure's elements in ``mode``: into ``out`` (n_owned_cells,
    n_plies, 6) for ``STRAINS`` and ``STRESSES``; ``sums_args`` (pattern, of_pattern, of_ply,
    kinds, per_ply, sums) for ``SUMS``. The arrays a mode does not use are empty."""
    data = element_data(structure)
    if out is None:
        out = np.zeros((0, 0, 6))
    if sums_args is None:
        empty = (np.zeros((0, 0, 8)), np.zeros((0, 0, 4)), np.zeros(0, np.int64))
        sums_args = (data.pattern, *empty, False, np.zeros((0, 0)))
    _ply_kernel(
        structure.X_base,
        structure.extra.vectors["X"].array.reshape(-1, 3),
        structure.base.u.x.array.reshape(-1, 3),
        structure.extra.vectors["u"].array.reshape(-1, 3),
        data.nodes,
        data.cells,
        data.plies,
        data.fractions,
        data.centre_maps,
        data.shear_roots,
        structure.base.finite,  # the damaged kernel's co-rotated frame (and objective)
        data.frames,
        # (the co-rotated frame moves the element: its shape is formed there)
        _NO_GEOMETRY if structure.base.finite else data.geometry,
        mode,
        data.stiffness,
        out,
        *sums_args,
    )


def _ply_field(structure, to_stress: bool, out: np.ndarray) -> np.ndarray:
    """The ply-centre strains, or stresses (``to_stress``), of every ply into ``out``
    (n_owned_cells, n_plies, 6), which the call overwrites where a ply is (zero it first for
    a layerwise model, whose cells hold some plies each). Returns ``out``."""
    _run_kernel(structure, STRESSES if to_stress else STRAINS, out)
    return out


def ply_strains(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) strain at each ply's mid-point (in-plane centre of its cell),
    shell frame (under finite kinematics the element's co-rotated one, as the ply damage
    law sees it), from whichever element (cell or subelement) holds the ply."""
    shape = (structure.base.n_owned_cells, structure.laminate.n_plies, 6)
    return _ply_field(structure, False, np.zeros(shape))


def ply_shear_scale(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) Voigt factors D that give each ply the stress its element
    carries, sigma = C (D epsilon): 1 but for the transverse shears, sqrt m_yz and sqrt m_xz
    of the ply in the element holding it (its share of the laminate's shear flow,
    ``RuleTable.ply_shear_factors``: on the rules that go ply by ply, the element's energy is
    that of the strain D epsilon, a ply's transverse shear not coupling to its other
    strains; a pre-integrated rule carries their mean)."""
    data = element_data(structure)
    scale = np.ones((structure.base.n_owned_cells, structure.laminate.n_plies, 6))
    _shear_scale(data.cells, data.plies.astype(np.int64), data.pattern, data.shear_roots, scale)
    return scale


def ply_stresses(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) shell-frame stress (MPa) at each ply's mid-point, as the
    element holding the ply carries it (its transverse shears its share of the laminate's
    shear flow, ``ply_shear_scale``): sigma = C (D strain)."""
    shape = (structure.base.n_owned_cells, structure.laminate.n_plies, 6)
    return _ply_field(structure, True, np.zeros(shape))


@dataclass(frozen=True)
class PlySums:
    """Rows of weighted sums of every cell's ply-centre stresses, sum_k w_rk sigma_k[i_r]
    (``ply_sums``): ``weights`` (n_rows, n_plies), e.g. ply thicknesses in mm for resultants
    (N/mm), and ``components`` (n_rows,) the Voigt component i_r of each row. ``forces``
    (n_rows,) bool, default none: transverse shear rows of the stress conjugate to the
    element's strain, D C (D eps), instead of the ply's C (D eps) (``ply_stresses``): its
    thickness integral is the element's shear force, where the plies' stresses, each the
    laminate's share over the ply, sum to a little more (``materials.laminate
    .ply_shear_factors``: by the root of the ratio of int g^2 / G to its ply means' sum)."""

    weights: np.ndarray
    components: np.ndarray
    forces: np.ndarray | None = None

    @cached_property
    def force_rows(self) -> np.ndarray:
        """(n_rows,) bool: ``forces``, or none."""
        if self.forces is None:
            return np.zeros(len(self.components), dtype=bool)
        return np.asarray(self.forces, dtype=bool)

    @cached_property
    def key(self) -> bytes:
        """What identifies these rows (the cache key of their matrices)."""
        components = np.asarray(self.components, np.int64).tobytes()
        return self.weights.tobytes() + components + self.force_rows.tobytes()


def _sum_matrices(data: ElementData, sums: PlySums) -> tuple:
    """(of_pattern (n_patterns, n_rows, 8), of_ply (n_plies, n_rows, 4), kinds (n_rows,)): the
    coefficients ``_ply_kernel`` takes ``sums``' rows with. Of a ply: a normal stress row
    w_rk C_k[i, NORMAL] (on the normal strains); a transverse shear row i (3: yz, 4: xz)
    w_rk C_k[i, 3], w_rk C_k[i, 4] (on gamma_yz, gamma_xz). Of a ply range [first, stop)
    (an element's): the sums of its plies' with weights 1 - zeta_k on the bottom strains and
    zeta_k on the top ones; a shear row's four: on gamma_yz bottom, top, gamma_xz bottom,
    top, with each ply's shear scales in the range (``ElementData.shear_roots``). Each range's
    are made once (``ElementData.range_matrices``)."""
    known = data.range_matrices
    if sums.key not in known:
        stiffness = data.stiffness
        of_ply = np.zeros((stiffness.shape[0], len(sums.components), 4))
        kinds = np.asarray(sums.components, dtype=np.int64).copy()
        for r, i in enumerate(kinds):
            if i in (3, 4):
                of_ply[:, r, :2] = sums.weights[r][:, None] * stiffness[:, i, 3:5]
                if sums.force_rows[r]:
                    kinds[r] = i + FORCE_ROW
            else:
                of_ply[:, r, :] = sums.weights[r][:, None] * stiffness[:, i, list(NORMAL)]
                kinds[r] = 0
        known[sums.key] = (of_ply, kinds)
    of_ply, kinds = known[sums.key]
    shear, f = kinds > 0, data.fractions
    of_pattern = np.zeros((len(data.patterns), len(kinds), 8))
    for p, (first, stop) in enumerate(data.patterns.tolist()):
        if (sums.key, first, stop) not in known:
            k = np.arange(first, stop)
            zeta = (0.5 * (f[k] + f[k + 1]) - f[first]) * (1.0 / (f[stop] - f[first]))
            # a shear row's plies with their shear scales in this range, C (D strain)
            # (``_scaled``): ply k's tau reads gamma_yz times r_yzk, gamma_xz times r_xzk
            root = data.shear_roots[p, first:stop]  # (plies, (xz, yz))
            scaled = of_ply[first:stop].copy()
            scaled[:, shear, 0] *= root[:, 1, None]
            scaled[:, shear, 1] *= root[:, 0, None]
            for r in np.flatnonzero(kinds >= FORCE_ROW):  # D C (D eps): once more
                scaled[:, r, :2] *= root[:, 1 if kinds[r] == 3 + FORCE_ROW else 0, None]
            low = np.einsum("k,krq->rq", 1.0 - zeta, scaled)
            high = np.einsum("k,krq->rq", zeta, scaled)
            matrix = np.zeros((len(kinds), 8))
            matrix[~shear, :4], matrix[~shear, 4:] = low[~shear], high[~shear]
            matrix[shear, 0:4:2], matrix[shear, 1:4:2] = low[shear, :2], high[shear, :2]
            known[sums.key, first, stop] = matrix
        of_pattern[p] = known[sums.key, first, stop]
    return of_pattern, of_ply, kinds


def ply_sums(structure, sums: PlySums, per_ply: bool = False) -> np.ndarray:
    """(n_owned_cells, n_rows): sum_k w_rk sigma_k[i_r] over the plies of each cell (``sums``),
    sigma_k the ply-centre stress of ``ply_stresses``, from whichever elements hold the plies.
    Each element's rows are a fixed matrix of its ply range times its strain at its bottom and
    top (exact along the axis of a prism, where the strain is linear in the height); other
    elements, or all with ``per_ply``, go ply by ply (``_ply_kernel``)."""
    data = element_data(structure)
    matrices = data.sum_matrices.get(sums.key)
    if matrices is None:
        matrices = data.sum_matrices[sums.key] = _sum_matrices(data, sums)
    of_pattern, of_ply, kinds = matrices
    out = np.zeros((structure.base.n_owned_cells, len(kinds)))
    args = (data.pattern, of_pattern, of_ply, kinds, per_ply, out)
    _run_kernel(structure, SUMS, sums_args=args)
    return out


def to_material_frame(stresses: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """Rotate Voigt stresses (..., n_plies, 6) of plies at ``angles_deg`` into their material
    frames (1 fibre, 2 transverse, 3 normal)."""
    out = np.empty_like(stresses)
    pairs = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
    for k, angle in enumerate(angles_deg):
        R = rotation_about_z(angle)  # columns: material axes in the shell frame
        sigma = np.zeros((*stresses.shape[:-2], 3, 3))
        for a, (i, j) in enumerate(pairs):
            sigma[..., i, j] = sigma[..., j, i] = stresses[..., k, a]
        material = np.einsum("ai,...ij,bj->...ab", R.T, sigma, R.T)
        for a, (i, j) in enumerate(pairs):
            out[..., k, a] = material[..., i, j]
    return out


@njit(cache=True)
def _hashin_field(stresses, params, out):
    """Largest Hashin exposure factor (fibre or matrix) of each (cell, ply) material-frame
    stress."""
    for c in range(stresses.shape[0]):
        for k in range(stresses.shape[1]):
            s = stresses[c, k]
            ft, fc, mt, mc = hashin_indices(s[0], s[1], s[2], s[3], s[4], s[5], params[k])
            out[c, k] = max(max(ft, fc), max(mt, mc))


def ply_failure_indices(structure) -> np.ndarray:
    """(n_cells, n_plies) largest Hashin index (fibre or matrix; 1 = failure) of each ply: the
    largest recorded so far when the ply damage model runs, else that of the current stress."""
    if structure.ply_damage:
        return structure.damage_state[:, :, S_FT : S_MC + 1].max(axis=2)
    plies = structure.laminate.plies
    params = np.array([structure.failures[p.material.name].as_array() for p in plies])
    material = to_material_frame(ply_stresses(structure), np.array([p.angle for p in plies]))
    out = np.zeros(material.shape[:2])
    _hashin_field(material, params, out)
    return out
