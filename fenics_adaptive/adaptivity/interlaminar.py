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
the cell's own resultants (``interlaminar_stresses``). All of it is linear in the plies'
stresses, so it is computed from a few weighted sums of them per boundary asked for
(``Recovery``: partial resultants and their trapezoidal integrals), which each element gives
from its strain at its bottom and top (``ply_fields.ply_sums``): the cost grows with the
boundaries estimated (the indicators ask for the delaminable interfaces), not with the plies.
Each pass over the cells is a numba kernel; the column averages are the only exchanges between
ranks (two per estimate). On a curved shell the plies' stresses are formed (its peel reads them
on the wall's curvature) and the sums taken from them. ``FaceGeometry`` keeps the reference
geometry they read.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
from dolfinx import la
from numba import njit

from fenics_adaptive.adaptivity.ply_fields import (
    PlySums,
    ply_shear_scale,
    ply_stresses,
    ply_sums,
)
from fenics_adaptive.element.geometry import quad_areas


@dataclass
class FaceGeometry:
    """The reference geometry the recovery reads, fixed for a structure: per owned cell the
    in-plane gradient operator of its bottom face at the centre (``d_dx``, ``d_dy`` (n, 4):
    d/dx of values at the face's four nodes, tensor order), per side (bottom, top) each node's
    tributary face area (mm^2, owned and ghost entries) and the owned nodes on it, the cells'
    centroids, and work vectors (the face tractions', both faces' on a node: 6 entries; the
    column averages' by width)."""

    d_dx: np.ndarray
    d_dy: np.ndarray
    areas: list[np.ndarray]
    owned_on_face: list[np.ndarray]
    traction: la.Vector
    centroids: np.ndarray  # (n_owned_cells, 3) mm
    # (n_owned_cells, 3) curvatures (1/mm) kappa_xx, kappa_yy, kappa_xy of a curved shell's
    # cells in their frames (``cell_curvatures``); None on a flat mesh or shell
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
        if len(frames):  # (a shell flat to round-off, a plate with a hole, has none)
            curvatures = cell_curvatures(structure.cell_vertices(), frames)
            if np.abs(curvatures).max(initial=0.0) * structure.laminate.thickness < 1e-12:
                curvatures = None
        return cls(
            d_dx, d_dy, areas, owned, la.vector(index_map, bs=6), centroids, curvatures, frames
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
    """table[node, :m] += values[cell, :m] and table[node, m] += 1 for every bottom node of
    every cell (``corners``: (n_cells, 4) local node numbers; ``values`` (n_cells, >= m);
    ``table`` (n_nodes, m + 1), zero before)."""
    m = table.shape[1] - 1
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


@dataclass(frozen=True)
class Recovery:
    """The estimate at some ply boundaries (``boundaries``, 0 the bottom face to n_plies the
    top one) as linear functionals of the ply-centre stresses, so that the plies' stresses
    are never formed (``ply_fields.ply_sums``).

    With t_k the ply thicknesses, z_j the boundaries' heights, h the laminate's, the recovered
    shear at boundary j is tau_j = -D(P_j) + (z_j / h) D(P_n), P_j = sum_{k<j} t_k sigma_k the
    in-plane stresses' partial resultant, averaged on the columns, D(s) = (d s_xx/dx +
    d s_xy/dy, d s_xy/dx + d s_yy/dy) at the cell's centre (the second term frees the top
    face). The peel stress integrates -div tau by the trapezoidal rule, sigma_zz,j = -div
    sum_l w_jl tau_l, and sum_l w_jl tau_l = -D(Q_j) + c_j D(P_n) with Q_j = sum_l w_jl P_l,
    c_j = sum_l w_jl z_l / h: a second column average of that, per boundary. The profile's
    thickness means (the bubble's scale, ``interlaminar_stresses``) are the same sums at the
    top, and for the peel once more, U = sum_j w_nj Q_j. Rows of ``sums``: P_j for every j
    in ``levels`` (the boundaries and the top face), then Q_j for every j, then U, each as
    three rows (xx, yy, xy); then the cell's own resultants sum_k t_k (sigma_zz, tau_xz,
    tau_yz)_k, the shears those conjugate to the element's strain (``PlySums.forces``: their
    sum is its shear force): 3 (2 L + 1) + 3 rows."""

    boundaries: np.ndarray  # (m,) the ply boundaries estimated, sorted
    levels: np.ndarray  # (L,) the boundaries and the top face
    at: np.ndarray  # (m,) each boundary's place in ``levels``
    sums: PlySums
    thickness: np.ndarray  # (n_plies,) mm
    trapezoid: np.ndarray  # (n_plies + 1, n_plies + 1) w_jl
    heights: np.ndarray  # (L,) z_j / h of the levels
    shifts: np.ndarray  # (L + 1,) c_j of the levels, then c_U = sum_j w_nj c_j

    @classmethod
    def of(cls, thickness: np.ndarray, boundaries) -> Recovery:
        t = np.asarray(thickness, dtype=float)
        n = len(t)
        boundaries = _boundary_indices(boundaries, n)
        levels = np.union1d(boundaries, [n]).astype(np.int64)
        z = np.concatenate([[0.0], np.cumsum(t)])
        h = z[-1]
        below = (np.arange(n)[None, :] < np.arange(n + 1)[:, None]).astype(float)  # [k < j]
        partial = below * t  # P_j's weights (n + 1, n)
        w = np.zeros((n + 1, n + 1))  # sigma_zz,j = -div sum_l w_jl tau_l
        for j in range(n + 1):
            for k in range(j):
                w[j, k] += 0.5 * t[k]
                w[j, k + 1] += 0.5 * t[k]
        second = w @ partial  # Q_j's weights
        c = w @ (z / h)
        in_plane = [*partial[levels], *second[levels], w[n] @ second]
        weights = [row for f in in_plane for row in (f, f, f)] + [t, t, t]
        components = [i for _ in in_plane for i in (0, 1, 5)] + [2, 4, 3]
        forces = np.zeros(len(components), dtype=bool)
        forces[-2:] = True  # the element's own shear force
        return cls(
            boundaries,
            levels,
            np.searchsorted(levels, boundaries),
            PlySums(np.array(weights), np.array(components, dtype=np.int64), forces),
            t,
            w,
            z[levels] / h,
            np.append(c[levels], w[n] @ c),
        )


# per structure (weakly held): its Recovery by boundaries
_RECOVERIES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _boundary_indices(boundaries, n_plies: int) -> np.ndarray:
    """The ply boundaries asked for, sorted and once each (int64); ValueError for one that is
    not a whole number from 0 (the bottom face) to ``n_plies`` (the top face)."""
    asked = np.asarray(list(boundaries), dtype=float).ravel()
    whole = np.round(asked)
    if np.any(whole != asked) or np.any((whole < 0) | (whole > n_plies)):
        raise ValueError(
            f"ply boundaries are whole numbers from 0 to {n_plies}, not {asked.tolist()}"
        )
    return np.unique(whole.astype(np.int64))


def recovery(structure, boundaries=None) -> Recovery:
    """The structure's ``Recovery`` at ``boundaries`` (all ply boundaries by default)."""
    known = _RECOVERIES.setdefault(structure, {})
    # by the boundaries as asked (the indicators ask with the same tuple at every
    # evaluation): checked and sorted once, not each time
    asked = None if boundaries is None else tuple(np.asarray(list(boundaries)).ravel().tolist())
    if asked not in known:
        n = structure.laminate.n_plies
        key = tuple(range(n + 1) if asked is None else _boundary_indices(asked, n).tolist())
        if key not in known:
            known[key] = Recovery.of([p.thickness for p in structure.laminate.plies], key)
        known[asked] = known[key]
    return known[asked]


@njit(cache=True)
def _gradient_pair(corners, table, d_dx, d_dy, c, f):
    """D(s) = (d s_xx/dx + d s_xy/dy, d s_xy/dx + d s_yy/dy) at cell c's centre of the column
    averages of the in-plane triple f of ``table`` (columns 3 f, 3 f + 1, 3 f + 2)."""
    dxx_dx, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * f)
    _, dyy_dy = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * f + 1)
    dxy_dx, dxy_dy = _centre_gradient(corners, table, d_dx, d_dy, c, 3 * f + 2)
    return dxx_dx + dxy_dy, dxy_dx + dyy_dy


@njit(cache=True)
def _shears(corners, table, d_dx, d_dy, heights, shifts, shear, lumped):
    """From the column averages of the rows P_j, Q_j, U (``Recovery``) in ``table``: the
    recovered shears shear[c, l] (tau_xz, tau_yz) at the levels and, for the second average,
    lumped[c] = (sum_l w_jl tau_l for each level j, then sum_j w_nj of those), flat."""
    n_levels = heights.shape[0]
    top = n_levels - 1
    for c in range(corners.shape[0]):
        top_x, top_y = _gradient_pair(corners, table, d_dx, d_dy, c, top)
        for j in range(n_levels):
            g_x, g_y = _gradient_pair(corners, table, d_dx, d_dy, c, j)
            shear[c, j, 0] = -g_x + heights[j] * top_x
            shear[c, j, 1] = -g_y + heights[j] * top_y
        for j in range(n_levels + 1):
            g_x, g_y = _gradient_pair(corners, table, d_dx, d_dy, c, n_levels + j)
            lumped[c, 2 * j] = -g_x + shifts[j] * top_x
            lumped[c, 2 * j + 1] = -g_y + shifts[j] * top_y


@njit(cache=True)
def _peels(corners, table, d_dx, d_dy, peel):
    """peel[c, j] = -div of the column averages of the pairs j of ``table`` (``_shears``'
    ``lumped``): the peel stress at each level, then its thickness integral."""
    for c in range(corners.shape[0]):
        for j in range(peel.shape[1]):
            d_x, _ = _centre_gradient(corners, table, d_dx, d_dy, c, 2 * j)
            _, d_y = _centre_gradient(corners, table, d_dx, d_dy, c, 2 * j + 1)
            peel[c, j] = -(d_x + d_y)


def _column_averages(structure, values: np.ndarray, m: int | None = None) -> np.ndarray:
    """Collective: (n_nodes, m + 1) the averages of the first ``m`` (default all) columns of
    per-cell ``values`` (n_cells, >= m; C-contiguous) over the cells around each bottom node,
    over all ranks (a view of a work vector, valid until the next call with the same m)."""
    width = (values.shape[1] if m is None else m) + 1
    if width - 1 > values.shape[1]:  # (the kernel reads the first m columns unchecked)
        raise ValueError(f"column averages of {width - 1} of {values.shape[1]} columns")
    sums = face_geometry(structure).sums_vector(structure, width)
    table = sums.array.reshape(-1, width)
    _corner_sums(structure.bottom_local, values, table)
    sums.scatter_reverse(la.InsertMode.add)
    sums.scatter_forward()
    _to_averages(table)
    return table


@dataclass
class _Profile:
    """A recovery's results per owned cell: ``shear`` (n, L, 2) and ``peel`` (n, L + 1: the
    levels, then the peel's thickness integral, N/mm) at the levels, the shears' thickness
    integrals ``shear_integral`` (n, 2) and the cell's own resultants ``own`` (n, 3:
    sigma_zz, tau_xz, tau_yz integrated over the thickness, N/mm)."""

    shear: np.ndarray
    peel: np.ndarray
    shear_integral: np.ndarray
    own: np.ndarray


def _recover(structure, rec: Recovery) -> _Profile:
    """Collective: the recovered profile of every owned cell at ``rec``'s levels. On a curved
    shell (whose cells are not prisms, and whose peel reads the plies' in-plane stresses on
    the curvatures) the plies' stresses are formed once and both taken from them; elsewhere
    the elements give the sums directly (``ply_fields.ply_sums``)."""
    geometry, corners = face_geometry(structure), structure.bottom_local
    hoop = None
    if geometry.curvatures is None:
        sums = ply_sums(structure, rec.sums)
    else:
        stresses = ply_stresses(structure)
        weights, components = rec.sums.weights, rec.sums.components
        sums = np.empty((len(stresses), len(components)))
        forces = rec.sums.force_rows

        def sum_rows(rows: np.ndarray, of: np.ndarray) -> None:
            part = np.empty((len(of), int(rows.sum())))
            _stress_sums(of, weights[rows], components[rows], part)
            sums[:, rows] = part

        sum_rows(~forces, stresses)
        if forces.any():  # D C (D eps): the plies' stresses times their shear scales
            sum_rows(forces, stresses * ply_shear_scale(structure))
        hoop = _hoop_peel(geometry.curvatures, stresses, rec)
    n_cells, n_levels = len(sums), len(rec.levels)
    table = _column_averages(structure, sums, 3 * (2 * n_levels + 1))
    shear = np.empty((n_cells, n_levels, 2))
    lumped = np.empty((n_cells, 2 * (n_levels + 1)))
    _shears(corners, table, geometry.d_dx, geometry.d_dy, rec.heights, rec.shifts, shear, lumped)
    table = _column_averages(structure, lumped)
    peel = np.empty((n_cells, n_levels + 1))
    _peels(corners, table, geometry.d_dx, geometry.d_dy, peel)
    if hoop is not None:
        peel += hoop
    return _Profile(
        shear,
        peel,
        np.ascontiguousarray(lumped[:, 2 * n_levels - 2 : 2 * n_levels]),
        np.ascontiguousarray(sums[:, -3:]),
    )


@njit(cache=True)
def _stress_sums(stresses, weights, components, out):
    """out[c, r] = sum_k weights[r, k] stresses[c, k, components[r]]: ``PlySums``' rows from
    the plies' stresses (n_cells, n_plies, 6)."""
    for c in range(stresses.shape[0]):
        for r in range(weights.shape[0]):
            i = components[r]
            total = 0.0
            for k in range(stresses.shape[1]):
                total += weights[r, k] * stresses[c, k, i]
            out[c, r] = total


def _hoop_peel(kappa: np.ndarray, stresses: np.ndarray, rec: Recovery) -> np.ndarray:
    """(n_cells, L + 1) what a curved shell's in-plane stresses (``stresses``: the plies',
    ``ply_stresses``) acting on the curvatures of its mid-surface (``kappa``:
    ``FaceGeometry.curvatures``) add to the peel stress at the levels, then to its thickness
    integral: sum_{k<j} t_k kappa_ab sigma_ab,k, the curvatures taken to each ply's centre,
    kappa / (1 + kappa z): a hoop stress on a tube's wall pulls its plies apart or presses
    them together."""
    t = rec.thickness
    level = np.cumsum(t) - 0.5 * t - 0.5 * t.sum()  # each ply's centre from the mid-surface
    per_ply = t * (
        kappa[:, 0, None] / (1.0 + kappa[:, 0, None] * level) * stresses[:, :, 0]
        + kappa[:, 1, None] / (1.0 + kappa[:, 1, None] * level) * stresses[:, :, 1]
        + 2.0 * kappa[:, 2, None] * stresses[:, :, 5]
    )
    partial = np.concatenate([np.zeros((len(stresses), 1)), np.cumsum(per_ply, axis=1)], axis=1)
    # (einsum, not a matrix product: numpy's BLAS would wake its thread pool per evaluation)
    integral = np.einsum("ck,k->c", partial, rec.trapezoid[-1])
    return np.column_stack([partial[:, rec.levels], integral])


def recovered_interface_stresses(structure, boundaries=None) -> np.ndarray:
    """(n_cells, m, 3): recovered (sigma_zz, tau_xz, tau_yz) in MPa at the ply ``boundaries``
    (m of them, sorted; default all, bottom face (0) to top face (n_plies)) of every owned
    cell. Each derivative is taken of the values averaged on the columns (the cells around
    each bottom node, over all ranks), bilinear over the cell's bottom face, at its centre
    (``Recovery`` says how it is summed). Collective."""
    rec = recovery(structure, boundaries)
    profile = _recover(structure, rec)
    out = np.empty((len(profile.shear), len(rec.boundaries), 3))
    out[:, :, 0] = profile.peel[:, rec.at]
    out[:, :, 1:] = profile.shear[:, rec.at]
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
    """out[c, side] = the mean of values[:, 3 side : 3 side + 3] (n_nodes, 6) over the four
    ``nodes[c]``."""
    for c in range(nodes.shape[0]):
        for i in range(3):
            j = 3 * side + i
            out[c, side, i] = 0.25 * (
                values[nodes[c, 0], j]
                + values[nodes[c, 1], j]
                + values[nodes[c, 2], j]
                + values[nodes[c, 3], j]
            )


@njit(cache=True)
def _per_area(force, nodes, areas, values, side):
    """values[node, 3 side : 3 side + 3] = force[node] / areas[node] for the ``nodes``."""
    for node in nodes:
        for i in range(3):
            values[node, 3 * side + i] = force[node, i] / areas[node]


def face_tractions(structure, nodal_force: np.ndarray) -> np.ndarray:
    """(n_cells, 2, 3): the traction (N/mm^2 = MPa, global axes) that nodal forces on the
    bottom (0) and top (1) faces apply to each owned cell, the mean over the face's four
    nodes of force / tributary area (a quarter of each adjacent cell's face): a force at a
    node is smeared over the cells around it, its total kept. ``nodal_force``: N on the base
    DOFs (owned, flat). Collective."""
    geometry = face_geometry(structure)
    n_owned = structure.base.V.dofmap.index_map.size_local
    force = nodal_force.reshape(-1, 3)[:n_owned]
    out = np.zeros((structure.base.n_owned_cells, 2, 3))
    # both faces in one vector (bottom x, y, z, top x, y, z): each call writes the owned nodes
    # of each face and the exchange the ghosts, so what it does not write stays zero
    values = geometry.traction.array.reshape(-1, 6)
    for side in range(2):
        _per_area(force, geometry.owned_on_face[side], geometry.areas[side], values, side)
    geometry.traction.scatter_forward()
    for side, nodes in enumerate((structure.bottom_local, structure.top_local)):
        _face_means(nodes, values, out, side)
    return out


def interlaminar_stresses(
    structure,
    t: float = 0.0,
    face_force: np.ndarray | None = None,
    boundaries=None,
) -> np.ndarray:
    """(n_cells, m, 3): estimate of (sigma_zz, tau_xz, tau_yz) in MPa at the ply
    ``boundaries`` (m of them, sorted; default all, bottom face (0) to top face (n_plies)) of
    every owned cell, at time t (s), from three load paths, each exact in the case it is made
    for:

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

    The indicators ask for the delaminable interfaces alone: the cost is in the rows of
    ``Recovery``, six per boundary. Collective.
    """
    rec = recovery(structure, boundaries)
    profile = _recover(structure, rec)
    n_cells = len(profile.own)
    on_faces = structure.loads.cell_face_tractions(t, n_cells)
    if face_force is not None:
        on_faces += face_tractions(structure, face_force)
    frames = face_geometry(structure).frames
    if len(frames) and len(on_faces):  # a curved shell: in each cell's frame, as its stresses
        on_faces = np.einsum("cij,csj->csi", frames, on_faces)
    estimate = np.empty((n_cells, len(rec.boundaries), 3))
    _fit_to_faces(
        on_faces,
        profile.shear,
        profile.peel,
        profile.shear_integral,
        profile.own,
        rec.thickness,
        rec.heights[rec.at],
        rec.at,
        estimate,
    )
    return estimate


@njit(cache=True)
def _fit_to_faces(on_faces, shear, peel, shear_integral, own, t, heights, at, estimate):
    """The recovered profile (``_Profile``: at the levels, the top face last, and its
    thickness integrals) at the boundaries ``at`` (their places among the levels; ``heights``
    z / h) into ``estimate`` (n_cells, m, 3), taken onto the face tractions ``on_faces``
    (n_cells, 2 (bottom, top), 3 (x, y, z)) by a linear correction, then onto the cells' own
    thickness integrals ``own`` of (sigma_zz, tau_xz, tau_yz) by the bubble
    6 (z/h)(1 - z/h) (``interlaminar_stresses``); integrals by the trapezoidal rule over the
    plies, as the bubble's own mean."""
    n_plies = t.shape[0]
    h = t.sum()
    top = shear.shape[1] - 1
    bubble_mean = 0.0
    zr = 0.0
    for k in range(n_plies):
        above = zr + t[k] / h
        bubble_mean += t[k] * 3.0 * (above * (1.0 - above) + zr * (1.0 - zr)) / h
        zr = above
    # a single ply: the rule sees the bubble at the faces alone, where it vanishes, and so
    # does it at every boundary asked for (the faces): nothing to scale
    per_bubble = 1.0 / (h * bubble_mean) if bubble_mean > 0.0 else 0.0
    face_component = (2, 0, 1)
    for c in range(estimate.shape[0]):
        for m in range(3):
            # sigma_i3 on the faces: the top face's outward normal is +z (sigma_i3 = T_i), the
            # bottom face's -z (sigma_i3 = -T_i)
            bottom = -on_faces[c, 0, face_component[m]]
            upper = on_faces[c, 1, face_component[m]]
            if m == 0:
                at_top, integral = peel[c, top], peel[c, top + 1]
            else:
                at_top, integral = shear[c, top, m - 1], shear_integral[c, m - 1]
            jump = upper - bottom - at_top
            # the linear correction's integral is h (bottom + jump / 2)
            missing = (own[c, m] - integral - h * (bottom + 0.5 * jump)) * per_bubble
            for j in range(at.shape[0]):
                value = peel[c, at[j]] if m == 0 else shear[c, at[j], m - 1]
                z = heights[j]
                estimate[c, j, m] = value + bottom + z * jump + missing * 6.0 * z * (1.0 - z)


def interface_initiation(recovered: np.ndarray, strength_n: float, strength_s: float):
    """sqrt((<sigma_zz>/N)^2 + (tau/S)^2) at the inner interfaces 1 .. n-1 of an estimate at
    every ply boundary (n_cells, n + 1, 3): (n_cells, n - 1)."""
    return initiation_index(recovered[:, 1:-1], strength_n, strength_s)


def initiation_index(estimate: np.ndarray, strength_n: float, strength_s: float) -> np.ndarray:
    """sqrt((<sigma_zz>/N)^2 + (tau/S)^2) (n_cells, m) of stresses (n_cells, m, 3: sigma_zz,
    tau_xz, tau_yz, MPa) against the strengths N and S (MPa)."""
    out = np.empty(estimate.shape[:2])
    _initiation(np.ascontiguousarray(estimate), 1.0 / strength_n, 1.0 / strength_s, out)
    return out


@njit(cache=True)
def _initiation(estimate, per_n, per_s, out):
    """``initiation_index`` with the strengths' reciprocals."""
    for c in range(out.shape[0]):
        for j in range(out.shape[1]):
            peel = max(estimate[c, j, 0], 0.0) * per_n
            shear_xz = estimate[c, j, 1] * per_s
            shear_yz = estimate[c, j, 2] * per_s
            out[c, j] = math.sqrt(peel * peel + shear_xz * shear_xz + shear_yz * shear_yz)
