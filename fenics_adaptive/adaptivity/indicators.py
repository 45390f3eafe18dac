"""Refinement indicators: which cells refine, at which interfaces, weak or strong (paper,
"Adaptivity").

Units: N, mm, s, tonne (stresses MPa).

- ``ply_failure`` (weak): a ply's Hashin index (``ply_damage.hashin_indices``: exposure
  factors, 1 = failure, fibre or matrix) reaches a fraction of 1 in a cell: the refinable
  interfaces nearest below and above that ply refine weakly, for a better through-thickness
  field around it (the paper: the bottom 0/90 interface refines when the lowermost ply fails).
- ``interface_stress`` (strong): the cohesive initiation criterion
  sqrt((<sigma_zz>/N)^2 + (tau/S)^2), evaluated at an interface with the out-of-plane stresses
  of ``interlaminar_stresses``, reaches a fraction of 1. Those are the recovered stresses
  below, taken onto the face tractions and scaled to the cell's own resultants. The unrefined
  shell's constitutive transverse stresses are
  poor (constant shear through the thickness, no peel), so they are recovered from equilibrium
  instead, as in the authors' ESL work: in-plane stresses of each ply, averaged on the nodes
  (columns), give in-plane derivatives on each cell; integrating
  d tau_xz/dz = -(d sigma_xx/dx + d sigma_xy/dy), d tau_yz/dz = -(d sigma_xy/dx + d sigma_yy/dy)
  from the free bottom face gives the shear stresses at the interfaces (a linear correction
  makes the top face free of shear traction too), and once more
  d sigma_zz/dz = -(d tau_xz/dx + d tau_yz/dy) the peel stress (not corrected: a pressure on
  the top face shows up there as it should).
- ``matrix_damage`` (strong): matrix damage has started in a ply next to a delaminable
  interface (matrix-crack-induced delamination).
- manual: at a time or a probe displacement, in an x range (the paper's TCB); see ``Manual``.
Refinement spreads to ``spread`` rings of neighbouring cells (cells sharing a node) and is never
undone.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
from dolfinx import la
from mpi4py import MPI
from numba import njit

from fenics_adaptive.adaptivity.events import Reasons, note
from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.element.solid_shell import NORMAL  # a monoclinic ply couples these
from fenics_adaptive.element.subelement import enhanced_parameter_maps, gather_nodes
from fenics_adaptive.materials.cohesive import cohesive_zone_length
from fenics_adaptive.materials.laminate import rotation_about_z
from fenics_adaptive.materials.ply_damage import S_D, S_FT, S_MC, hashin_indices
from fenics_adaptive.settings.adaptivity import IndicatorSettings
from fenics_adaptive.settings.kinds import InterfaceState


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


@njit(cache=True)
def _ply_center_strains(
    X_base,
    X_extra,
    u_base,
    u_extra,
    nodes,
    cells,
    plies,
    fractions,
    alpha_center,
    stiffness,
    root,
    to_stress,
    out,
):
    """Small strain (Voigt, engineering shears) at the in-plane centre of every ply of every
    element, at the ply's mid-thickness, into out[cell, ply]; with the element's enhanced
    thickness strain alpha_center[e] g(zeta) / |det J| (``alpha_center``: its parameter at the
    in-plane centre). ``to_stress``: the ply's stress D C_k (D strain) instead (``stiffness``
    (n_plies, 6, 6), monoclinic; D the element's shear scale, ``root`` (n_elements, 2) its
    sqrt k_xz, sqrt k_yz: ``ply_stresses``).

    On the element's axis (xi = eta = 1/2) the trilinear shape functions' in-plane derivatives
    are (1 - zeta) times the bottom face's plus zeta times the top face's, and the thickness
    derivative does not depend on zeta: the Jacobian and the displacement gradient (in the
    element's coordinates) are formed once per element, as a bottom, a top and a normal part,
    and combined per ply."""
    n_base = X_base.shape[0]
    X = np.empty((8, 3))
    u = np.empty((8, 3))
    parts = np.empty((2, 3, 5))  # (X, u), component, (d_xi bottom, top, d_eta bottom, top, d_zeta)
    J = np.empty((3, 3))
    G = np.empty((3, 3))
    Jinv = np.empty((3, 3))
    grad = np.empty((3, 3))
    ends = np.empty((2, 3, 3))
    strain = np.empty(6)
    enhanced = 0.0  # alpha / |det J| of the element (a prism) or of the ply
    for e in range(nodes.shape[0]):
        gather_nodes(nodes[e], n_base, X_base, X_extra, X)
        gather_nodes(nodes[e], n_base, u_base, u_extra, u)
        parts[:] = 0.0
        for a in range(8):
            s_xi = 1.0 if a & 1 else -1.0
            s_eta = 1.0 if (a >> 1) & 1 else -1.0
            top = (a >> 2) & 1
            s_zeta = 1.0 if top else -1.0
            for i in range(3):
                for f in range(2):
                    value = X[a, i] if f == 0 else u[a, i]
                    parts[f, i, top] += 0.5 * s_xi * value
                    parts[f, i, 2 + top] += 0.5 * s_eta * value
                    parts[f, i, 4] += 0.25 * s_zeta * value
        first, stop = plies[e, 0], plies[e, 1]
        bottom, top_f = fractions[first], fractions[stop]
        # a prism (top face a translate of the bottom one): J does not vary along the axis,
        # and grad u = G J^-1 is linear in zeta there: two products per element
        prism = True
        for i in range(3):
            if parts[0, i, 0] != parts[0, i, 1] or parts[0, i, 2] != parts[0, i, 3]:
                prism = False
        if prism:
            for i in range(3):
                J[i, 0] = parts[0, i, 0]
                J[i, 1] = parts[0, i, 2]
                J[i, 2] = parts[0, i, 4]
            enhanced = alpha_center[e] / abs(_inverse_3x3(J, Jinv))
            for f in range(2):  # grad u on the bottom (0) and top (1) face
                for i in range(3):
                    g0, g1, g2 = parts[1, i, f], parts[1, i, 2 + f], parts[1, i, 4]
                    for r in range(3):
                        ends[f, i, r] = g0 * Jinv[0, r] + g1 * Jinv[1, r] + g2 * Jinv[2, r]
        span = 1.0 / (top_f - bottom)
        for k in range(first, stop):
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
                enhanced = alpha_center[e] / abs(_inverse_3x3(J, Jinv))
                for i in range(3):
                    for r in range(3):
                        grad[i, r] = (
                            G[i, 0] * Jinv[0, r] + G[i, 1] * Jinv[1, r] + G[i, 2] * Jinv[2, r]
                        )
            c = cells[e]
            strain[0] = grad[0, 0]
            strain[1] = grad[1, 1]
            strain[2] = grad[2, 2] + enhanced * (zeta - 0.5)
            strain[3] = grad[1, 2] + grad[2, 1]
            strain[4] = grad[0, 2] + grad[2, 0]
            strain[5] = grad[0, 1] + grad[1, 0]
            if to_stress:  # monoclinic plies: the normal and the transverse shear parts apart
                for a in range(4):
                    i = NORMAL[a]
                    total = 0.0
                    for b in range(4):
                        total += stiffness[k, i, NORMAL[b]] * strain[NORMAL[b]]
                    out[c, k, i] = total
                yz = root[e, 1] * strain[3]
                xz = root[e, 0] * strain[4]
                out[c, k, 3] = root[e, 1] * (stiffness[k, 3, 3] * yz + stiffness[k, 3, 4] * xz)
                out[c, k, 4] = root[e, 0] * (stiffness[k, 4, 3] * yz + stiffness[k, 4, 4] * xz)
            else:
                for i in range(6):
                    out[c, k, i] = strain[i]


@njit(cache=True)
def _centre_parameters(maps, nodes, n_base, u_base, u_extra, out):
    """out[e] = sum over element e's nodes a and components i of maps[e, a, i] u[a, i]: its
    enhanced parameter at the in-plane centre (``ElementData.centre_maps``)."""
    for e in range(nodes.shape[0]):
        total = 0.0
        for a in range(8):
            node = nodes[e, a]
            for i in range(3):
                value = u_base[node, i] if node < n_base else u_extra[node - n_base, i]
                total += maps[e, a, i] * value
        out[e] = total


@njit(cache=True)
def _shear_scale(cells, plies, root, scale):
    """scale[cell, ply, 3 (yz), 4 (xz)] = root[e, 1], root[e, 0] for the plies [first, stop)
    of every element e (``ply_shear_scale``); the rest of ``scale`` untouched."""
    for e in range(cells.shape[0]):
        for ply in range(plies[e, 0], plies[e, 1]):
            scale[cells[e], ply, 3] = root[e, 1]
            scale[cells[e], ply, 4] = root[e, 0]


@dataclass
class ElementData:
    """What the ply strains and stresses read of the structure's solid elements, which change
    only when it refines: the elements (``Structure.elements``), the map from each one's
    nodal displacements (8, 3) to its enhanced thickness strain parameter at the in-plane
    centre (the mean of its four lines' small-strain maps, undamaged:
    ``RuleTable.enhanced_parameters``), the plies' shear scale (``ply_shear_scale``) and
    stiffnesses, and where each (cell, interface) keeps its cohesive damage. ``subelements``:
    the structure's ``SubelementSet`` they were made for (a
    refinement makes a new one); ``keys``: each element's (cell, first ply, stop ply) as one
    integer, by which a refinement keeps the maps of the elements it did not change."""

    subelements: object
    nodes: np.ndarray
    cells: np.ndarray
    plies: np.ndarray
    keys: np.ndarray
    centre_maps: np.ndarray  # (n_elements, 8, 3) mm^3 / mm
    shear_scale: np.ndarray  # (n_owned_cells, n_plies, 6)
    shear_roots: np.ndarray  # (n_elements, 2) sqrt k_xz, sqrt k_yz of each element
    stiffness: np.ndarray  # (n_plies, 6, 6) MPa, shell frame
    alpha: np.ndarray  # (n_elements,) scratch for the centre parameters
    cohesive_rows: np.ndarray  # (m, 3) cell, interface, damage row (``Structure.damage_rows``)
    fractions: np.ndarray  # (n_plies + 1,) the ply boundaries' height in the laminate, 0 to 1
    stresses: np.ndarray  # (n_owned_cells, n_plies, 6) the indicators' ply stresses, zero at first

    @classmethod
    def of(cls, structure, previous: ElementData | None = None) -> ElementData:
        """The structure's element data now; the maps of elements ``previous`` holds (the
        same cell and plies: the same nodes and rule) are taken from it."""
        nodes, cells, plies = structure.elements()
        table = structure.rule_table
        n_plies = structure.laminate.n_plies
        keys = (cells * (n_plies + 1) + plies[:, 0]) * (n_plies + 1) + plies[:, 1]
        centre_maps = np.empty((len(nodes), 8, 3))
        todo = np.ones(len(nodes), dtype=bool)
        if previous is not None and len(previous.keys):
            order = np.argsort(previous.keys)
            at = np.minimum(np.searchsorted(previous.keys, keys, sorter=order), len(order) - 1)
            todo = previous.keys[order[at]] != keys
            centre_maps[~todo] = previous.centre_maps[order[at[~todo]]]
        maps = np.zeros((int(todo.sum()), 4, 8, 3))
        enhanced_parameter_maps(
            structure.gather(nodes[todo], "X"), table.rule_of(plies[todo]), *table.packed, maps
        )
        centre_maps[todo] = maps.mean(axis=1)
        scale = np.ones((structure.base.n_owned_cells, n_plies, 6))
        root = np.sqrt(table.shear_factors(plies))  # (n_elements, 2)
        _shear_scale(cells, plies.astype(np.int64), root, scale)
        if previous is not None:
            stiffness = previous.stiffness
        else:
            stiffness = np.array(structure.laminate.ply_stiffnesses()).reshape(n_plies, 6, 6)
        return cls(
            structure.refined_cells.subelements,
            nodes,
            cells,
            plies,
            keys,
            centre_maps,
            scale,
            np.ascontiguousarray(root),
            stiffness,
            np.zeros(len(nodes)),
            np.array(
                [(c, i, row) for (c, i), row in structure.damage_rows.items()], dtype=np.int64
            ).reshape(-1, 3),
            np.asarray(structure.laminate.ply_fractions, dtype=float),
            np.zeros((structure.base.n_owned_cells, n_plies, 6)),
        )


@dataclass
class FaceGeometry:
    """The reference geometry the recovery reads, fixed for a structure: per owned cell the
    in-plane gradient operator of its bottom face at the centre (``d_dx``, ``d_dy`` (n, 4):
    d/dx of values at the face's four nodes, tensor order), per side (bottom, top) each node's
    tributary face area (mm^2, owned and ghost entries) and the owned nodes on it, the cells'
    centroids, and work vectors (the face tractions', the column averages' by width)."""

    d_dx: np.ndarray
    d_dy: np.ndarray
    areas: list[np.ndarray]
    owned_on_face: list[np.ndarray]
    traction: la.Vector
    centroids: np.ndarray  # (n_owned_cells, 3) mm
    sums: dict[int, la.Vector] = field(default_factory=dict)

    @classmethod
    def of(cls, structure) -> FaceGeometry:
        X = structure.X_base[structure.bottom_local]  # (n, 4, 3)
        d_xi = np.array([-0.5, 0.5, -0.5, 0.5])
        d_eta = np.array([-0.5, -0.5, 0.5, 0.5])
        J = np.stack(
            [
                np.stack([X[:, :, 0] @ d_xi, X[:, :, 0] @ d_eta], axis=1),
                np.stack([X[:, :, 1] @ d_xi, X[:, :, 1] @ d_eta], axis=1),
            ],
            axis=1,
        )  # (n, 2 (x, y), 2 (xi, eta))
        inv = np.linalg.inv(J) if len(J) else np.zeros((0, 2, 2))  # (n, (xi, eta), (x, y))
        d_dx = inv[:, 0, 0, None] * d_xi + inv[:, 1, 0, None] * d_eta
        d_dy = inv[:, 0, 1, None] * d_xi + inv[:, 1, 1, None] * d_eta
        index_map = structure.base.V.dofmap.index_map
        n_owned = index_map.size_local
        areas, owned = [], []
        for nodes in (structure.bottom_local, structure.top_local):
            area = quad_areas(structure.X_base[nodes])  # the faces' nodes are in tensor order
            tributary = la.vector(index_map, bs=1)
            np.add.at(tributary.array, nodes.ravel(), np.repeat(0.25 * area, 4))
            tributary.scatter_reverse(la.InsertMode.add)
            tributary.scatter_forward()
            areas.append(tributary.array.copy())
            on_face = np.unique(nodes.ravel())
            owned.append(on_face[on_face < n_owned])
        centroids = structure.cell_vertices().mean(axis=1)
        return cls(d_dx, d_dy, areas, owned, la.vector(index_map, bs=3), centroids)

    def sums_vector(self, structure, width: int) -> la.Vector:
        """A zeroed work vector of block size ``width`` on the base nodes."""
        if width not in self.sums:
            self.sums[width] = la.vector(structure.base.V.dofmap.index_map, bs=width)
        vector = self.sums[width]
        vector.array.fill(0.0)
        return vector


# per structure (weakly held): its FaceGeometry, and its ElementData until it refines
_GEOMETRY: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_ELEMENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def face_geometry(structure) -> FaceGeometry:
    """The structure's ``FaceGeometry``, made on first use."""
    if structure not in _GEOMETRY:
        _GEOMETRY[structure] = FaceGeometry.of(structure)
    return _GEOMETRY[structure]


def element_data(structure) -> ElementData:
    """The structure's ``ElementData``, made again after it refined."""
    data = _ELEMENTS.get(structure)
    if data is None or data.subelements is not structure.refined_cells.subelements:
        data = _ELEMENTS[structure] = ElementData.of(structure, data)
    return data


def _ply_field(structure, to_stress: bool, out: np.ndarray) -> np.ndarray:
    """The ply-centre strains, or stresses (``to_stress``), of every ply into ``out``
    (n_owned_cells, n_plies, 6), which the call overwrites where a ply is (zero it first for
    a layerwise model, whose cells hold some plies each). Returns ``out``."""
    data = element_data(structure)
    u_base = structure.base.u.x.array.reshape(-1, 3)
    u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
    _centre_parameters(data.centre_maps, data.nodes, structure.n_base, u_base, u_extra, data.alpha)
    _ply_center_strains(
        structure.X_base,
        structure.extra.vectors["X"].array.reshape(-1, 3),
        u_base,
        u_extra,
        data.nodes,
        data.cells,
        data.plies,
        data.fractions,
        data.alpha,
        data.stiffness,
        data.shear_roots,
        to_stress,
        out,
    )
    return out


def ply_strains(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) strain at each ply's mid-point (in-plane centre of its cell),
    shell frame, from whichever element (cell or subelement) holds the ply."""
    shape = (structure.base.n_owned_cells, structure.laminate.n_plies, 6)
    return _ply_field(structure, False, np.zeros(shape))


def ply_shear_scale(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) Voigt factors D that give each ply the stress its element
    carries, sigma = D C (D epsilon): 1 but for the transverse shears, sqrt k_yz and sqrt k_xz
    of the element holding the ply (its shear correction, ``RuleTable.shear_factors``; the
    stress whose work with the strain is the element's energy, a ply's transverse shear not
    coupling to its other strains). Do not modify: it is kept until the structure refines."""
    return element_data(structure).shear_scale


def ply_stresses(structure, strains: np.ndarray | None = None) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) shell-frame stress (MPa) at each ply's mid-point, as the
    element holding the ply carries it (its transverse shear with the element's shear
    correction, ``ply_shear_scale``): sigma = D C (D strain), of ``strains`` if given."""
    data = element_data(structure)
    if strains is None:
        shape = (structure.base.n_owned_cells, structure.laminate.n_plies, 6)
        return _ply_field(structure, True, np.zeros(shape))
    D = data.shear_scale
    return D * np.einsum("kij,ckj->cki", data.stiffness, D * strains)


def _indicator_stresses(structure) -> np.ndarray:
    """``ply_stresses`` into the indicators' own array (``ElementData.stresses``): valid until
    the next call."""
    return _ply_field(structure, True, element_data(structure).stresses)


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


# ---------------------------------------------------------------------------- recovery
@njit(cache=True)
def _corner_sums(corners, values, table):
    """table[node, :m] += values[cell] and table[node, m] += 1 for every bottom node of every
    cell (``corners``: (n_cells, 4) local node numbers; ``values`` (n_cells, m); ``table``
    (n_nodes, m + 1), zero before)."""
    m = values.shape[1]
    for c in range(corners.shape[0]):
        for a in range(4):
            node = corners[c, a]
            for j in range(m):
                table[node, j] += values[c, j]
            table[node, m] += 1.0


@njit(cache=True)
def _to_averages(table):
    """Divide each row's sums table[node, :m] by its count table[node, m] (at least 1)."""
    m = table.shape[1] - 1
    for node in range(table.shape[0]):
        per = 1.0 / max(table[node, m], 1.0)
        for j in range(m):
            table[node, j] *= per


@njit(cache=True)
def _centre_gradient(corners, averages, d_dx, d_dy, c, j):
    """(d/dx, d/dy) at cell c's centre of column j of the column ``averages``, bilinear over
    the bottom face."""
    g_x = 0.0
    g_y = 0.0
    for a in range(4):
        value = averages[corners[c, a], j]
        g_x += d_dx[c, a] * value
        g_y += d_dy[c, a] * value
    return g_x, g_y


@njit(cache=True)
def _in_plane_stresses(stresses, out):
    """out[c, 3 k + (0, 1, 2)] = (sigma_xx, sigma_yy, tau_xy) of ply k of cell c."""
    for c in range(stresses.shape[0]):
        for k in range(stresses.shape[1]):
            out[c, 3 * k] = stresses[c, k, 0]
            out[c, 3 * k + 1] = stresses[c, k, 1]
            out[c, 3 * k + 2] = stresses[c, k, 5]


@njit(cache=True)
def _shear_profile(corners, table, d_dx, d_dy, t, out, shear):
    """The transverse shears at the ply boundaries, out[c, :, 1:] (tau_xz, tau_yz), from the
    column averages of the plies' in-plane stresses ``table`` (n_nodes, 3 n_plies + 1): their
    in-plane gradients integrated through the thickness from the free bottom face (d tau_xz /
    dz = -(d sigma_xx / dx + d tau_xy / dy), d tau_yz / dz = -(d tau_xy / dx + d sigma_yy /
    dy)), less the linear part that makes the top face free too. ``shear`` (n_cells,
    2 (n_plies + 1)): the same, flat, for the next column average."""
    n_plies = t.shape[0]
    h = t.sum()
    for c in range(corners.shape[0]):
        out[c, 0, 1] = 0.0
        out[c, 0, 2] = 0.0
        for k in range(n_plies):
            dxx_dx, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * k)
            _, dyy_dy = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * k + 1)
            dxy_dx, dxy_dy = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * k + 2)
            out[c, k + 1, 1] = out[c, k, 1] - (dxx_dx + dxy_dy) * t[k]
            out[c, k + 1, 2] = out[c, k, 2] - (dxy_dx + dyy_dy) * t[k]
        top_xz = out[c, n_plies, 1]
        top_yz = out[c, n_plies, 2]
        z = 0.0
        for j in range(n_plies + 1):
            out[c, j, 1] -= z / h * top_xz
            out[c, j, 2] -= z / h * top_yz
            shear[c, 2 * j] = out[c, j, 1]
            shear[c, 2 * j + 1] = out[c, j, 2]
            if j < n_plies:
                z += t[j]


@njit(cache=True)
def _peel_profile(corners, table, d_dx, d_dy, t, out):
    """The peel stress at the ply boundaries, out[c, :, 0], from the column averages of the
    shears ``table`` (n_nodes, 2 (n_plies + 1) + 1): d sigma_zz / dz = -(d tau_xz / dx +
    d tau_yz / dy) integrated from the bottom face (trapezoidal in each ply)."""
    n_plies = t.shape[0]
    for c in range(corners.shape[0]):
        out[c, 0, 0] = 0.0
        below, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 0)
        below += _centre_gradient(corners, table, d_dx, d_dy, c, 1)[1]
        for k in range(n_plies):
            above, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 2 * (k + 1))
            above += _centre_gradient(corners, table, d_dx, d_dy, c, 2 * (k + 1) + 1)[1]
            out[c, k + 1, 0] = out[c, k, 0] - 0.5 * (above + below) * t[k]
            below = above


def _column_table(structure, width: int) -> tuple[la.Vector, np.ndarray]:
    """A zeroed work vector of ``width`` values per base node and its (n_nodes, width) view."""
    sums = face_geometry(structure).sums_vector(structure, width)
    return sums, sums.array.reshape(-1, width)


def _average_on_columns(sums: la.Vector, table: np.ndarray) -> None:
    """Collective: complete the column sums on the owners, then on the ghosts, and make them
    averages (``_to_averages``)."""
    sums.scatter_reverse(la.InsertMode.add)
    sums.scatter_forward()
    _to_averages(table)


def recovered_interface_stresses(structure, stresses: np.ndarray | None = None) -> np.ndarray:
    """(n_cells, n_plies + 1, 3): recovered (sigma_zz, tau_xz, tau_yz) in MPa at every ply
    boundary of every owned cell, bottom face (0) to top face (n_plies). Each derivative is
    taken of the values averaged on the columns (the cells around each bottom node, over all
    ranks), bilinear over the cell's bottom face, at its centre. Collective."""
    stresses = ply_stresses(structure) if stresses is None else stresses
    n_cells, n_plies, _ = stresses.shape
    t = np.array([p.thickness for p in structure.laminate.plies])
    geometry, corners = face_geometry(structure), structure.bottom_local
    out = np.empty((n_cells, n_plies + 1, 3))
    in_plane = np.empty((n_cells, 3 * n_plies))
    _in_plane_stresses(stresses, in_plane)
    sums, table = _column_table(structure, 3 * n_plies + 1)
    _corner_sums(corners, in_plane, table)
    _average_on_columns(sums, table)
    shear = np.empty((n_cells, 2 * (n_plies + 1)))
    _shear_profile(corners, table, geometry.d_dx, geometry.d_dy, t, out, shear)
    sums, table = _column_table(structure, 2 * (n_plies + 1) + 1)
    _corner_sums(corners, shear, table)
    _average_on_columns(sums, table)
    _peel_profile(corners, table, geometry.d_dx, geometry.d_dy, t, out)
    return out


@njit(cache=True)
def _face_means(nodes, values, out, side):
    """out[c, side] = the mean of values (n_nodes, 3) over the four ``nodes[c]``."""
    for c in range(nodes.shape[0]):
        for i in range(3):
            out[c, side, i] = 0.25 * (
                values[nodes[c, 0], i]
                + values[nodes[c, 1], i]
                + values[nodes[c, 2], i]
                + values[nodes[c, 3], i]
            )


def face_tractions(structure, nodal_force: np.ndarray) -> np.ndarray:
    """(n_cells, 2, 3): the traction (N/mm^2 = MPa, global axes) that nodal forces on the
    bottom (0) and top (1) faces apply to each owned cell, the mean over the face's four
    nodes of force / tributary area (a quarter of each adjacent cell's face): a force at a
    node is smeared over the cells around it, its total kept. ``nodal_force``: N on the base
    DOFs (owned, flat). Collective."""
    geometry = face_geometry(structure)
    index_map = structure.base.V.dofmap.index_map
    n_owned = index_map.size_local
    force = nodal_force.reshape(-1, 3)
    out = np.zeros((structure.base.n_owned_cells, 2, 3))
    traction = geometry.traction
    for side, nodes in enumerate((structure.bottom_local, structure.top_local)):
        on_face = geometry.owned_on_face[side]
        traction.array.fill(0.0)
        values = traction.array.reshape(-1, 3)
        values[on_face] = force[:n_owned][on_face] / geometry.areas[side][on_face, None]
        traction.scatter_forward()
        _face_means(nodes, values, out, side)
    return out


def interlaminar_stresses(
    structure,
    t: float = 0.0,
    stresses: np.ndarray | None = None,
    face_force: np.ndarray | None = None,
) -> np.ndarray:
    """(n_cells, n_plies + 1, 3): estimate of (sigma_zz, tau_xz, tau_yz) in MPa at every ply
    boundary of every owned cell, bottom face (0) to top face (n_plies), at time t (s), from
    three load paths, each exact in the case it is made for:

    - the *variation* through the thickness from equilibrium recovery
      (``recovered_interface_stresses``): the shear and peel that in-plane stress gradients
      carry (bending under transverse shear, a pressure's bending);
    - the *face tractions* on the top and bottom faces: the face loads
      (``ResolvedLoads.cell_face_tractions``) and ``face_force`` (N on the base DOFs, owned: the
      reactions of prescribed motions and contact forces, ``face_tractions``): the values at
      the faces, a linear correction taking the recovered profile onto them;
    - the cell's *own resultants*: the thickness mean of its constitutive sigma_zz, tau_xz,
      tau_yz, which the element gets right whatever loads it (its thickness stretch and its
      transverse shear are in equilibrium with what acts on the cell: the opening of a DCB's
      arms, a punch, a prescribed motion or contact on the faces): a parabola that vanishes on
      both faces, 6 (z/h)(1 - z/h), scaled so that the estimate has the cell's mean.

    ``stresses``: the ply-centre stresses (``ply_stresses``) if already computed. Collective.
    """
    stresses = ply_stresses(structure) if stresses is None else stresses
    estimate = recovered_interface_stresses(structure, stresses)
    thickness = np.array([p.thickness for p in structure.laminate.plies])
    on_faces = structure.loads.cell_face_tractions(t, len(stresses))
    if face_force is not None:
        on_faces += face_tractions(structure, face_force)
    _fit_to_faces(on_faces, stresses, thickness, estimate)
    return estimate


@njit(cache=True)
def _fit_to_faces(on_faces, stresses, t, estimate):
    """Take the recovered profiles ``estimate`` (n_cells, n_plies + 1, 3), in place, onto the
    face tractions ``on_faces`` (n_cells, 2 (bottom, top), 3 (x, y, z)) by a linear correction,
    then onto the cells' own thickness means of (sigma_zz, tau_xz, tau_yz) by the bubble
    6 (z/h)(1 - z/h) (``interlaminar_stresses``); means linear between ply boundaries."""
    n_plies = t.shape[0]
    h = t.sum()
    zr = np.empty(n_plies + 1)  # z / h at the ply boundaries
    zr[0] = 0.0
    for k in range(n_plies):
        zr[k + 1] = zr[k] + t[k] / h
    bubble_mean = 0.0
    for k in range(n_plies):
        bubble_mean += t[k] * 3.0 * (zr[k + 1] * (1.0 - zr[k + 1]) + zr[k] * (1.0 - zr[k])) / h
    own_component = (2, 4, 3)  # sigma_zz, tau_xz, tau_yz in the Voigt stress
    face_component = (2, 0, 1)
    for c in range(estimate.shape[0]):
        for m in range(3):
            # sigma_i3 on the faces: the top face's outward normal is +z (sigma_i3 = T_i), the
            # bottom face's -z (sigma_i3 = -T_i)
            bottom = -on_faces[c, 0, face_component[m]]
            top = on_faces[c, 1, face_component[m]]
            jump = top - bottom - estimate[c, n_plies, m]
            for j in range(n_plies + 1):
                estimate[c, j, m] += bottom + zr[j] * jump
            own = 0.0
            mean = 0.0
            for k in range(n_plies):
                own += t[k] * stresses[c, k, own_component[m]]
                mean += t[k] * 0.5 * (estimate[c, k + 1, m] + estimate[c, k, m])
            missing = (own - mean) / h / bubble_mean
            for j in range(n_plies + 1):
                estimate[c, j, m] += missing * 6.0 * zr[j] * (1.0 - zr[j])


def interface_initiation(recovered: np.ndarray, strength_n: float, strength_s: float):
    """sqrt((<sigma_zz>/N)^2 + (tau/S)^2) at the inner interfaces 1 .. n-1: (n_cells, n - 1)."""
    out = np.empty((recovered.shape[0], recovered.shape[1] - 2))
    _initiation(recovered, 1.0 / strength_n, 1.0 / strength_s, out)
    return out


@njit(cache=True)
def _initiation(recovered, per_n, per_s, out):
    """``interface_initiation`` with the strengths' reciprocals."""
    for c in range(out.shape[0]):
        for j in range(out.shape[1]):
            peel = max(recovered[c, j + 1, 0], 0.0) * per_n
            shear_xz = recovered[c, j + 1, 1] * per_s
            shear_yz = recovered[c, j + 1, 2] * per_s
            out[c, j] = math.sqrt(peel * peel + shear_xz * shear_xz + shear_yz * shear_yz)


# ---------------------------------------------------------------------------- decisions
def indicator_requests(
    structure,
    settings: IndicatorSettings,
    strengths: tuple[float, float],
    t: float = 0.0,
    reasons: Reasons | None = None,
    face_force: np.ndarray | None = None,
):
    """The refinements the indicators ask for on this rank's cells at time t: (cell,
    interface, kind). ``strengths``: the cohesive law's normal and shear strengths (MPa).
    ``reasons``: when given, each request's indicator and value are noted in it (``note``).
    ``face_force``: the supports' and contact forces on the base DOFs (N, owned), for the
    interlaminar estimate (``interlaminar_stresses``).
    Collective (the stress recovery averages over neighbouring cells on all ranks)."""
    requests = []
    state = structure.interface_state
    if settings.strong_after is not None:
        for interface in structure.interfaces.delaminate:
            due = (state[:, interface - 1] == InterfaceState.WEAK) & (
                structure.weak_since[:, interface - 1] + settings.strong_after <= t
            )
            asked = [(int(c), interface, InterfaceState.STRONG) for c in np.flatnonzero(due)]
            waited = t - structure.weak_since[[c for c, _, _ in asked], interface - 1]
            note(reasons, asked, "strong_after", waited)
            requests += asked
    if settings.ply_failure is not None:
        index = ply_failure_indices(structure)
        weak = sorted(set(structure.interfaces.refine) | set(structure.interfaces.delaminate))
        for ply in range(index.shape[1]):
            cells = np.flatnonzero(index[:, ply] >= settings.ply_failure)
            # the refinable interfaces nearest below (<= ply) and above (>= ply + 1) the ply
            below = [i for i in weak if i <= ply]
            above = [i for i in weak if i >= ply + 1]
            for interface in ([below[-1]] if below else []) + ([above[0]] if above else []):
                todo = cells[state[cells, interface - 1] == InterfaceState.NONE]
                asked = [(int(c), interface, InterfaceState.WEAK) for c in todo]
                note(reasons, asked, "ply_failure", index[todo, ply])
                requests += asked
    if settings.matrix_damage:
        damage = structure.damage_state[:, :, S_D]
        for interface in structure.interfaces.delaminate:
            cracked = (damage[:, interface - 1] > 0.0) | (damage[:, interface] > 0.0)
            todo = np.flatnonzero(cracked & (state[:, interface - 1] < InterfaceState.STRONG))
            asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
            worst = np.maximum(damage[todo, interface - 1], damage[todo, interface])
            note(reasons, asked, "matrix_damage", worst)
            requests += asked
    if settings.interface_stress is not None:
        stresses = _indicator_stresses(structure)
        estimate = interlaminar_stresses(structure, t, stresses, face_force)
        index = interface_initiation(estimate, *strengths)
        for interface in structure.interfaces.delaminate:
            flagged = (index[:, interface - 1] >= settings.interface_stress) & (
                state[:, interface - 1] < InterfaceState.STRONG
            )
            todo = np.flatnonzero(flagged)
            asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
            note(reasons, asked, "interface_stress", index[todo, interface - 1])
            requests += asked
    return requests


def sublaminate_thicknesses(laminate, delaminate: tuple[int, ...]) -> np.ndarray:
    """(n_plies - 1,) mm: at each ply interface, the thinner of the two sublaminates it
    separates once every interface in ``delaminate`` (1-based) has split: the plies up to the
    next delaminable interface (or face) below and above."""
    t = np.array([p.thickness for p in laminate.plies])
    z = np.concatenate([[0.0], np.cumsum(t)])
    bounds = np.array(sorted({0, len(t), *delaminate}))
    out = np.zeros(len(t) - 1)
    for interface in range(1, len(t)):
        below = bounds[bounds < interface].max()
        above = bounds[bounds > interface].min()
        out[interface - 1] = min(z[interface] - z[below], z[above] - z[interface])
    return out


def front_distances(structure, law, distance: float | None = None) -> np.ndarray:
    """(n_plies - 1,) mm: how far around a started delamination each interface refines
    strongly (``front_requests``); 0 where the interface may not delaminate. ``distance``: the
    user's, or None for each interface's own: the length of its process zone when fully grown
    (``cohesive.cohesive_zone_length`` of ``law``, with the larger transverse modulus of the
    two plies it joins) plus two thicknesses of the thinner sublaminate it separates. The zone
    then develops inside the refined region, and ahead of it the band where the peel and shear
    stresses of the bonded part decay (over a few thicknesses of the more compliant, thinner
    arm: a beam on an elastic foundation, a film on a substrate) is refined as well, so that the
    border constraint, which holds the interface to the unrefined neighbour's kinematics, acts
    on neither."""
    plies = structure.laminate.plies
    out = np.zeros(len(plies) - 1)
    delaminate = tuple(structure.interfaces.delaminate)
    if distance is not None:
        out[[i - 1 for i in delaminate]] = distance
        return out
    sublaminate = sublaminate_thicknesses(structure.laminate, delaminate)
    for i in delaminate:
        modulus = max(plies[i - 1].material.E2, plies[i].material.E2)
        out[i - 1] = cohesive_zone_length(law, modulus) + 2.0 * sublaminate[i - 1]
    return out


def default_interval(structure) -> float:
    """Time (s) between indicator evaluations when the config gives none: the time a shear
    wave, sqrt(G12 / rho) of the slowest ply, takes to cross the narrowest band that
    ``front_distances`` keeps refined ahead of a process zone (two thicknesses of the thinner
    sublaminate at an interface that may refine). No delamination front runs faster than that
    wave, so between two evaluations a front cannot cross the band."""
    plies = structure.laminate.plies
    interfaces = sorted(set(structure.interfaces.refine) | set(structure.interfaces.delaminate))
    if interfaces:
        thick = sublaminate_thicknesses(structure.laminate, tuple(interfaces))
        band = 2.0 * min(thick[i - 1] for i in interfaces)
    else:
        band = 2.0 * structure.laminate.thickness
    speed = min(math.sqrt(p.material.G12 / p.material.rho) for p in plies)
    return band / speed


@njit(cache=True)
def _nearest_within(points, sources, reach, out):
    """out[k]: distance from points[k] to the nearest of ``sources`` (sorted by x), inf if none
    lies within ``reach``: only the sources whose x lies within reach are measured."""
    n = sources.shape[0]
    for k in range(points.shape[0]):
        x = points[k, 0]
        lo, hi = 0, n
        while lo < hi:  # first source with x >= x - reach
            mid = (lo + hi) // 2
            if sources[mid, 0] < x - reach:
                lo = mid + 1
            else:
                hi = mid
        best = np.inf
        j = lo
        while j < n and sources[j, 0] <= x + reach:
            d = np.sqrt(
                (sources[j, 0] - x) ** 2
                + (sources[j, 1] - points[k, 1]) ** 2
                + (sources[j, 2] - points[k, 2]) ** 2
            )
            if d < best:
                best = d
            j += 1
        out[k] = best if best <= reach else np.inf


def front_requests(
    structure, distances: np.ndarray, reasons: Reasons | None = None
) -> list[tuple[int, int, int]]:
    """Collective: strong refinements that keep every started delamination inside the refined
    region: at each interface i, the cells whose centroid lies within ``distances[i - 1]``
    (mm, ``front_distances``) of the centroid of a cell whose cohesive element there has
    damage > 0 (on any rank), not yet strong there. Noted in ``reasons``, when given, as
    ``front`` with the distance (mm) to the nearest such cell."""
    state = structure.interface_state
    centroids = face_geometry(structure).centroids
    cells, interfaces, rows = element_data(structure).cohesive_rows.T
    hit = (distances[interfaces - 1] > 0.0) & (structure.cohesive.damage[rows].max(axis=1) > 0.0)
    started = {int(i): cells[hit & (interfaces == i)] for i in np.unique(interfaces[hit])}
    # every rank takes part, whatever it holds: the interfaces in order, one gather each
    everywhere = structure.comm.allgather(sorted(started))
    requests = []
    for interface in sorted(set().union(*everywhere)):
        local = centroids[started.get(interface, np.zeros(0, np.int64))].reshape(-1, 3)
        sources = np.vstack(structure.comm.allgather(local))
        sources = np.ascontiguousarray(sources[np.argsort(sources[:, 0], kind="stable")])
        nearest = np.empty(len(centroids))
        _nearest_within(centroids, sources, distances[interface - 1], nearest)
        todo = np.flatnonzero(
            np.isfinite(nearest) & (state[:, interface - 1] < InterfaceState.STRONG)
        )
        asked = [(int(c), interface, InterfaceState.STRONG) for c in todo]
        note(reasons, asked, "front", nearest[todo])
        requests += asked
    return requests


# ---------------------------------------------------------------------------- spreading
def spread(structure, requests: list[tuple[int, int, int]], rings: int) -> list:
    """Add the cells sharing a node with a requested cell (``rings`` times), with the same
    interface and kind. Collective (neighbours may live on other ranks)."""
    n_interfaces = structure.interface_state.shape[1]
    for _ in range(rings):
        if not structure.comm.allreduce(len(requests), op=MPI.SUM):
            break
        marks = la.vector(structure.base.V.dofmap.index_map, bs=2 * n_interfaces)
        table = marks.array.reshape(-1, 2, n_interfaces)
        nodes = np.hstack([structure.bottom_local, structure.top_local])
        for cell, interface, kind in requests:
            table[nodes[cell], kind - 1, interface - 1] = 1.0
        marks.scatter_reverse(la.InsertMode.add)
        marks.scatter_forward()
        touched = table[nodes] > 0  # (n_cells, 8, 2, n_if)
        hit = touched.any(axis=1)
        requests = [
            (int(c), int(i) + 1, int(k) + 1) for c, k, i in zip(*np.nonzero(hit), strict=True)
        ]
    return requests
