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

import numpy as np
from dolfinx import la
from mpi4py import MPI
from numba import njit

from fenics_adaptive.adaptivity.events import Reasons, note
from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.element.subelement import gather_nodes
from fenics_adaptive.materials.cohesive import cohesive_zone_length
from fenics_adaptive.materials.laminate import rotation_about_z
from fenics_adaptive.materials.ply_damage import S_D, S_FT, S_MC, hashin_indices
from fenics_adaptive.settings.adaptivity import IndicatorSettings
from fenics_adaptive.settings.kinds import InterfaceState


@njit(cache=True)
def _inverse_3x3(A, out):
    det = (
        A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
        - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
        + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])
    )
    out[0, 0] = (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) / det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    out[1, 0] = (A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]) / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 0] = (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]) / det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det


@njit(cache=True)
def _ply_center_strains(
    X_base, X_extra, u_base, u_extra, nodes, cells, plies, fractions, alpha_center, out
):
    """Small strain (Voigt, engineering shears) at the in-plane centre of every ply of every
    element, at the ply's mid-thickness, into out[cell, ply]; with the element's enhanced
    thickness strain alpha_center[e] g(zeta) / |det J| (``alpha_center``: its parameter at the
    in-plane centre).

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
        for k in range(first, stop):
            zeta = (0.5 * (fractions[k] + fractions[k + 1]) - bottom) / (top_f - bottom)
            for i in range(3):
                J[i, 0] = (1.0 - zeta) * parts[0, i, 0] + zeta * parts[0, i, 1]
                J[i, 1] = (1.0 - zeta) * parts[0, i, 2] + zeta * parts[0, i, 3]
                J[i, 2] = parts[0, i, 4]
                G[i, 0] = (1.0 - zeta) * parts[1, i, 0] + zeta * parts[1, i, 1]
                G[i, 1] = (1.0 - zeta) * parts[1, i, 2] + zeta * parts[1, i, 3]
                G[i, 2] = parts[1, i, 4]
            _inverse_3x3(J, Jinv)
            det = (
                J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1])
                - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
                + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0])
            )
            for i in range(3):
                for r in range(3):
                    grad[i, r] = G[i, 0] * Jinv[0, r] + G[i, 1] * Jinv[1, r] + G[i, 2] * Jinv[2, r]
            c = cells[e]
            out[c, k, 0] = grad[0, 0]
            out[c, k, 1] = grad[1, 1]
            out[c, k, 2] = grad[2, 2] + alpha_center[e] * (zeta - 0.5) / abs(det)
            out[c, k, 3] = grad[1, 2] + grad[2, 1]
            out[c, k, 4] = grad[0, 2] + grad[2, 0]
            out[c, k, 5] = grad[0, 1] + grad[1, 0]


@njit(cache=True)
def _ply_stress(stiffness, scale, strains, out):
    """out[c, k] = D C_k (D strains[c, k]), D = diag(scale[c, k]) (``ply_stresses``)."""
    scaled = np.empty(6)
    for c in range(strains.shape[0]):
        for k in range(strains.shape[1]):
            for j in range(6):
                scaled[j] = scale[c, k, j] * strains[c, k, j]
            for i in range(6):
                total = 0.0
                for j in range(6):
                    total += stiffness[k, i, j] * scaled[j]
                out[c, k, i] = scale[c, k, i] * total


@njit(cache=True)
def _sum_at_corners(corners, values, table):
    """table[node, :m] += values[cell] and table[node, m] += 1 for every node of every cell
    (``corners``: (n_cells, 4) local node numbers; table: (n_nodes, m + 1))."""
    m = values.shape[1]
    for c in range(corners.shape[0]):
        for a in range(corners.shape[1]):
            node = corners[c, a]
            for j in range(m):
                table[node, j] += values[c, j]
            table[node, m] += 1.0


def ply_strains(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) strain at each ply's mid-point (in-plane centre of its cell),
    shell frame, from whichever element (cell or subelement) holds the ply."""
    nodes, cells, plies = structure.elements()
    out = np.zeros((structure.base.n_owned_cells, structure.laminate.n_plies, 6))
    table = structure.rule_table
    alpha = table.enhanced_parameters(
        structure.gather(nodes, "X"), structure.gather(nodes, "u"), plies
    )
    _ply_center_strains(
        structure.X_base,
        structure.extra.vectors["X"].array.reshape(-1, 3),
        structure.base.u.x.array.reshape(-1, 3),
        structure.extra.vectors["u"].array.reshape(-1, 3),
        nodes,
        cells,
        plies,
        structure.laminate.ply_fractions,
        alpha.mean(axis=1),  # alpha at the centre: the mean of its four Gauss-line values
        out,
    )
    return out


def ply_shear_scale(structure) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) Voigt factors D that give each ply the stress its element
    carries, sigma = D C (D epsilon): 1 but for the transverse shears, sqrt k_yz and sqrt k_xz
    of the element holding the ply (its shear correction, ``RuleTable.shear_factors``; the
    stress whose work with the strain is the element's energy, a ply's transverse shear not
    coupling to its other strains)."""
    n_plies = structure.laminate.n_plies
    scale = np.ones((structure.base.n_owned_cells, n_plies, 6))
    _, cells, plies = structure.elements()
    root = np.sqrt(structure.rule_table.shear_factors(plies))  # (n_elements, 2)
    for ply in range(n_plies):
        holds = (plies[:, 0] <= ply) & (ply < plies[:, 1])
        scale[cells[holds], ply, 3] = root[holds, 1]  # yz
        scale[cells[holds], ply, 4] = root[holds, 0]  # xz
    return scale


def ply_stresses(structure, strains: np.ndarray | None = None) -> np.ndarray:
    """(n_owned_cells, n_plies, 6) shell-frame stress (MPa) at each ply's mid-point, as the
    element holding the ply carries it (its transverse shear with the element's shear
    correction, ``ply_shear_scale``)."""
    strains = ply_strains(structure) if strains is None else strains
    stiffness = np.array(structure.laminate.ply_stiffnesses())  # (n_plies, 6, 6)
    scale = ply_shear_scale(structure)
    out = np.empty_like(strains)
    _ply_stress(stiffness, scale, strains, out)
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


# ---------------------------------------------------------------------------- recovery
def _column_average(structure, values: np.ndarray) -> np.ndarray:
    """Average of per-cell values (n_cells, m) over the cells around each bottom node (over all
    ranks), returned per cell and column: (n_cells, 4, m)."""
    m = values.shape[1]
    index_map = structure.base.V.dofmap.index_map
    sums = la.vector(index_map, bs=m + 1)
    table = sums.array.reshape(-1, m + 1)
    _sum_at_corners(structure.bottom_local, np.ascontiguousarray(values), table)
    sums.scatter_reverse(la.InsertMode.add)
    sums.scatter_forward()
    averages = table[:, :m] / np.maximum(table[:, m:], 1.0)
    return averages[structure.bottom_local]


def _in_plane_gradients(structure, nodal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d/dx and d/dy at each cell's centre of values (n_cells, 4, m) at its bottom nodes
    (bilinear in the bottom face, tensor order)."""
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
    inv = np.linalg.inv(J)  # (n, 2 (xi, eta), 2 (x, y))
    v_xi = np.einsum("a,nam->nm", d_xi, nodal)
    v_eta = np.einsum("a,nam->nm", d_eta, nodal)
    d_x = inv[:, 0, 0, None] * v_xi + inv[:, 1, 0, None] * v_eta
    d_y = inv[:, 0, 1, None] * v_xi + inv[:, 1, 1, None] * v_eta
    return d_x, d_y


def recovered_interface_stresses(structure, stresses: np.ndarray | None = None) -> np.ndarray:
    """(n_cells, n_plies + 1, 3): recovered (sigma_zz, tau_xz, tau_yz) in MPa at every ply
    boundary of every owned cell, bottom face (0) to top face (n_plies)."""
    stresses = ply_stresses(structure) if stresses is None else stresses
    n_cells, n_plies, _ = stresses.shape
    t = np.array([p.thickness for p in structure.laminate.plies])
    z = np.concatenate([[0.0], np.cumsum(t)])
    h = z[-1]
    in_plane = stresses[:, :, [0, 1, 5]].reshape(n_cells, -1)  # sxx, syy, sxy per ply
    d_x, d_y = _in_plane_gradients(structure, _column_average(structure, in_plane))
    d_x = d_x.reshape(n_cells, n_plies, 3)
    d_y = d_y.reshape(n_cells, n_plies, 3)
    slope_xz = -(d_x[:, :, 0] + d_y[:, :, 2])  # d tau_xz / dz in each ply
    slope_yz = -(d_x[:, :, 2] + d_y[:, :, 1])
    tau = np.zeros((n_cells, n_plies + 1, 2))
    tau[:, 1:, 0] = np.cumsum(slope_xz * t, axis=1)
    tau[:, 1:, 1] = np.cumsum(slope_yz * t, axis=1)
    tau -= (z / h)[None, :, None] * tau[:, -1:, :]  # traction-free top face too
    d_x, d_y = _in_plane_gradients(structure, _column_average(structure, tau.reshape(n_cells, -1)))
    div = (
        (d_x.reshape(n_cells, n_plies + 1, 2)[:, :, 0])
        + (d_y.reshape(n_cells, n_plies + 1, 2)[:, :, 1])
    )
    sigma_zz = np.zeros((n_cells, n_plies + 1))
    sigma_zz[:, 1:] = -np.cumsum(0.5 * (div[:, 1:] + div[:, :-1]) * t, axis=1)
    return np.concatenate([sigma_zz[:, :, None], tau], axis=2)


def _through_thickness_mean(values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Mean over the thickness of values (n_cells, n_plies + 1, m) at the ply boundaries,
    linear in each ply (t: ply thicknesses, mm): (n_cells, m)."""
    return np.einsum("k,ckm->cm", t, 0.5 * (values[:, 1:] + values[:, :-1])) / t.sum()


def face_tractions(structure, nodal_force: np.ndarray) -> np.ndarray:
    """(n_cells, 2, 3): the traction (N/mm^2 = MPa, global axes) that nodal forces on the
    bottom (0) and top (1) faces apply to each owned cell, the mean over the face's four
    nodes of force / tributary area (a quarter of each adjacent cell's face): a force at a
    node is smeared over the cells around it, its total kept. ``nodal_force``: N on the base
    DOFs (owned, flat). Collective."""
    index_map = structure.base.V.dofmap.index_map
    n_owned = index_map.size_local
    out = np.zeros((structure.base.n_owned_cells, 2, 3))
    for side, nodes in enumerate((structure.bottom_local, structure.top_local)):
        area = quad_areas(structure.X_base[nodes])  # the faces' nodes are in tensor order
        areas = la.vector(index_map, bs=1)
        np.add.at(areas.array, nodes.ravel(), np.repeat(0.25 * area, 4))
        areas.scatter_reverse(la.InsertMode.add)
        areas.scatter_forward()
        force = np.zeros((n_owned + index_map.num_ghosts, 3))
        force[:n_owned] = nodal_force.reshape(-1, 3)[:n_owned]
        traction = la.vector(index_map, bs=3)
        on_face = np.unique(nodes.ravel())
        on_face = on_face[on_face < n_owned]
        traction.array.reshape(-1, 3)[on_face] = force[on_face] / areas.array[on_face, None]
        traction.scatter_forward()
        out[:, side] = traction.array.reshape(-1, 3)[nodes].mean(axis=1)
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
    recovered = recovered_interface_stresses(structure, stresses)
    thickness = np.array([p.thickness for p in structure.laminate.plies])
    z = np.concatenate([[0.0], np.cumsum(thickness)]) / thickness.sum()  # z/h, ply boundaries
    # sigma_i3 on the faces: the top face's outward normal is +z (sigma_i3 = T_i), the bottom
    # face's -z (sigma_i3 = -T_i); components in the (sigma_zz, tau_xz, tau_yz) order
    order = [2, 0, 1]
    on_faces = structure.loads.cell_face_tractions(t, len(stresses))
    if face_force is not None:
        on_faces += face_tractions(structure, face_force)
    bottom, top = -on_faces[:, 0, order], on_faces[:, 1, order]
    estimate = recovered + bottom[:, None, :]
    estimate += z[None, :, None] * (top - bottom - recovered[:, -1, :])[:, None, :]
    bubble = 6.0 * z * (1.0 - z)
    own = np.einsum("k,ckm->cm", thickness, stresses[:, :, [2, 4, 3]]) / thickness.sum()
    missing = own - _through_thickness_mean(estimate, thickness)
    # the bubble's mean as the estimate's is measured (linear between ply boundaries)
    bubble_mean = np.dot(thickness, 0.5 * (bubble[1:] + bubble[:-1])) / thickness.sum()
    estimate += (missing / bubble_mean)[:, None, :] * bubble[None, :, None]
    return estimate


def interface_initiation(recovered: np.ndarray, strength_n: float, strength_s: float):
    """sqrt((<sigma_zz>/N)^2 + (tau/S)^2) at the inner interfaces 1 .. n-1: (n_cells, n - 1)."""
    inner = recovered[:, 1:-1, :]
    peel = np.maximum(inner[:, :, 0], 0.0) / strength_n
    shear = np.hypot(inner[:, :, 1], inner[:, :, 2]) / strength_s
    return np.sqrt(peel**2 + shear**2)


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
        stresses = ply_stresses(structure)
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
    damage = structure.cohesive.damage
    state = structure.interface_state
    centroids = structure.cell_vertices().mean(axis=1)
    started = {}
    for (cell, interface), row in structure.damage_rows.items():
        if distances[interface - 1] > 0.0 and damage[row].max() > 0.0:
            started.setdefault(interface, []).append(cell)
    # every rank takes part, whatever it holds: the interfaces in order, one gather each
    everywhere = structure.comm.allgather(sorted(started))
    requests = []
    for interface in sorted(set().union(*everywhere)):
        local = centroids[started.get(interface, [])].reshape(-1, 3)
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
