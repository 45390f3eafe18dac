"""The interlaminar stress estimate of unrefined and weakly refined cells, (sigma_zz, tau_xz,
tau_yz) at every ply boundary (``interlaminar_stresses``), and the cohesive initiation
criterion on it (``interface_initiation``): what the ``interface_stress`` indicator reads.

Units: N, mm, s, tonne (stresses MPa).

The unrefined shell's constitutive transverse stresses are poor (constant shear through the
thickness, no peel), so they are recovered from equilibrium instead, as in the authors' ESL
work (``recovered_interface_stresses``): in-plane stresses of each ply, averaged on the nodes
(columns), give in-plane derivatives on each cell; integrating
d tau_xz/dz = -(d sigma_xx/dx + d sigma_xy/dy), d tau_yz/dz = -(d sigma_xy/dx + d sigma_yy/dy)
from the free bottom face gives the shear stresses at the interfaces (a linear correction makes
the top face free of shear traction too), and once more d sigma_zz/dz = -(d tau_xz/dx +
d tau_yz/dy) the peel stress. That profile is then taken onto the face tractions and scaled to
the cell's own resultants (``interlaminar_stresses``). Each pass over the cells is a numba
kernel; the column averages are the only exchanges between ranks (two per estimate).
``FaceGeometry`` keeps the reference geometry they read.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
from dolfinx import la
from numba import njit

from fenics_adaptive.adaptivity.ply_fields import ply_stresses
from fenics_adaptive.element.geometry import quad_areas


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
    # (n_owned_cells, 3) curvatures (1/mm) kappa_xx, kappa_yy, kappa_xy of a curved shell's
    # cells in their frames (``cell_curvatures``); None on a flat mesh
    curvatures: np.ndarray | None = None
    # (n_owned_cells, 3, 3) a curved shell's cell frames (``LayeredModel.element_frames``),
    # (0, 3, 3) on a flat mesh
    frames: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    sums: dict[int, la.Vector] = field(default_factory=dict)

    @classmethod
    def of(cls, structure) -> FaceGeometry:
        X = structure.X_base[structure.bottom_local]  # (n, 4, 3)
        frames = structure.base.element_frames(np.arange(len(X)))
        if len(frames):  # a curved shell: the derivatives along each cell's own axes 1, 2
            X = np.einsum("cij,caj->cai", frames, X)
        d_dx, d_dy = face_gradients(X)
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
        curvatures = None
        if len(frames):
            curvatures = cell_curvatures(structure.cell_vertices(), frames)
        return cls(
            d_dx, d_dy, areas, owned, la.vector(index_map, bs=3), centroids, curvatures, frames
        )

    def sums_vector(self, structure, width: int) -> la.Vector:
        """A zeroed work vector of block size ``width`` on the base nodes."""
        if width not in self.sums:
            self.sums[width] = la.vector(structure.base.V.dofmap.index_map, bs=width)
        vector = self.sums[width]
        vector.array.fill(0.0)
        return vector


def face_gradients(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d_dx, d_dy) (n, 4): d/dx and d/dy at the centre of quadrilaterals X (n, 4, 3; tensor
    order; their x and y components taken, the plane of the quadrilateral) of values at their
    four vertices, bilinear."""
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
    return d_dx, d_dy


# per structure (weakly held): its FaceGeometry
_GEOMETRY: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def face_geometry(structure) -> FaceGeometry:
    """The structure's ``FaceGeometry``, made on first use: collective then (its tributary
    areas are summed over ranks), as every caller here is."""
    if structure not in _GEOMETRY:
        _GEOMETRY[structure] = FaceGeometry.of(structure)
    return _GEOMETRY[structure]


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
def _peel_profile(corners, table, d_dx, d_dy, t, out, curvatures, in_plane, curved, level):
    """The peel stress at the ply boundaries, out[c, :, 0], from the column averages of the
    shears ``table`` (n_nodes, 2 (n_plies + 1) + 1): d sigma_zz / dz = -(d tau_xz / dx +
    d tau_yz / dy) integrated from the bottom face (trapezoidal in each ply); on a ``curved``
    shell plus the in-plane stresses ``in_plane`` (n_cells, 3 n_plies) acting on the
    curvatures (n_cells, 3: kappa_xx, kappa_yy, kappa_xy, 1/mm) of the mid-surface, taken to
    each ply's centre at ``level`` (n_plies,) mm from it, kappa_ab sigma_ab: a hoop stress on a
    tube's wall pulls its plies apart or presses them together."""
    n_plies = t.shape[0]
    for c in range(corners.shape[0]):
        out[c, 0, 0] = 0.0
        below, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 0)
        below += _centre_gradient(corners, table, d_dx, d_dy, c, 1)[1]
        for k in range(n_plies):
            above, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 2 * (k + 1))
            above += _centre_gradient(corners, table, d_dx, d_dy, c, 2 * (k + 1) + 1)[1]
            out[c, k + 1, 0] = out[c, k, 0] - 0.5 * (above + below) * t[k]
            if curved:  # the surface through the ply's centre: kappa / (1 + kappa z)
                z = level[k]
                out[c, k + 1, 0] += t[k] * (
                    curvatures[c, 0] / (1.0 + curvatures[c, 0] * z) * in_plane[c, 3 * k]
                    + curvatures[c, 1] / (1.0 + curvatures[c, 1] * z) * in_plane[c, 3 * k + 1]
                    + 2.0 * curvatures[c, 2] * in_plane[c, 3 * k + 2]
                )
            below = above


def _column_averages(structure, values: np.ndarray) -> np.ndarray:
    """Collective: (n_nodes, m + 1) the averages of per-cell ``values`` (n_cells, m) over the
    cells around each bottom node, over all ranks (a view of a work vector, valid until the
    next call with the same m)."""
    width = values.shape[1] + 1
    sums = face_geometry(structure).sums_vector(structure, width)
    table = sums.array.reshape(-1, width)
    _corner_sums(structure.bottom_local, values, table)
    sums.scatter_reverse(la.InsertMode.add)
    sums.scatter_forward()
    _to_averages(table)
    return table


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
    table = _column_averages(structure, in_plane)
    shear = np.empty((n_cells, 2 * (n_plies + 1)))
    _shear_profile(corners, table, geometry.d_dx, geometry.d_dy, t, out, shear)
    table = _column_averages(structure, shear)
    curved = geometry.curvatures is not None
    curvatures = geometry.curvatures if curved else np.zeros((0, 3))
    level = np.cumsum(t) - 0.5 * t - 0.5 * t.sum()  # each ply's centre from the mid-surface
    _peel_profile(
        corners, table, geometry.d_dx, geometry.d_dy, t, out, curvatures, in_plane, curved, level
    )
    return out


def cell_curvatures(X: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(n, 3) the curvatures kappa_xx, kappa_yy, kappa_xy (1/mm) of the mid-surfaces of cells
    with vertices X (n, 8, 3), in their frames (n, 3, 3): kappa_ab = e_a . d n / d x_b at the
    centre, n the unit vertical edges (a curved shell's edges run along its normals),
    differentiated on the mid-surface (the mean of the bottom and top faces). Positive where the
    surface bends away from its normal (a tube with outward normals: 1 / R around it)."""
    edges = X[:, 4:] - X[:, :4]
    normals = np.einsum("cij,caj->cai", frames, edges / np.linalg.norm(edges, axis=2)[..., None])
    middle = np.einsum("cij,caj->cai", frames, 0.5 * (X[:, :4] + X[:, 4:]))
    d_dx, d_dy = face_gradients(middle)
    dn_dx = np.einsum("ca,cai->ci", d_dx, normals)
    dn_dy = np.einsum("ca,cai->ci", d_dy, normals)
    return np.column_stack([dn_dx[:, 0], dn_dy[:, 1], 0.5 * (dn_dx[:, 1] + dn_dy[:, 0])])


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
    frames = face_geometry(structure).frames
    if len(frames) and len(on_faces):  # a curved shell: in each cell's frame, as its stresses
        on_faces = np.einsum("cij,csj->csi", frames, on_faces)
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
