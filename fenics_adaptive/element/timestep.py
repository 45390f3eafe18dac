"""Stable time step of the central-difference scheme.

Units: mm, s, tonne, N.

Solids: dt <= L_e / c per (sub)element, L_e = volume / largest face area, c = the fastest
dilatational wave speed of its plies. Cohesive node pairs (nodes 1, 2 with masses m1, m2 joined by
a penalty spring k = K A_node, A_node the node's share of the interface area):
dt <= 2 / sqrt(k (1/m1 + 1/m2)). The caller applies the safety factor.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fenics_adaptive.element.subelement import _fill_line, _inverse3, _line_matrix, _monomials

# Local vertex lists of the six faces of a reference hexahedron (DOLFINx numbering), each face
# in tensor order (``geometry.quad_areas``).
HEX_FACES = np.array(
    [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 4, 5], [2, 3, 6, 7], [0, 2, 4, 6], [1, 3, 5, 7]]
)


def characteristic_lengths(X: np.ndarray) -> np.ndarray:
    """Volume / largest face area (mm) of hexahedra with vertex coordinates X (n, 8, 3) mm."""
    out = np.empty(len(X))
    _characteristic_lengths(np.ascontiguousarray(X, dtype=np.float64), out)
    return out


def hexahedron_volumes(X: np.ndarray) -> np.ndarray:
    """Exact volumes (mm^3) of trilinear hexahedra X (n, 8, 3) mm (2x2x2 Gauss on det J)."""
    out = np.empty(len(X))
    _hexahedron_volumes(np.ascontiguousarray(X, dtype=np.float64), out)
    return out


# (a stable-step check runs over every cell and subelement at each refinement, and over the
# deformed cells at every history row under finite kinematics: numpy took 2.8 us a cell).
# The Jacobian is the element kernels' own (``subelement``: monomials, vertical lines).
@njit(cache=True, inline="always")
def _volume(X, e, bx, line):
    """|det J| summed over the 2x2x2 Gauss points on [0, 1]^3 of hexahedron e (each weight
    1/8); scratch ``bx`` (8, 3), ``line`` (4, 3, 3)."""
    g = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))
    _monomials(X[e], bx)
    volume = 0.0
    for xi in g:
        for eta in g:
            _fill_line(bx, bx, xi, eta, line)  # (the displacement rows unread)
            for z in g:
                det, _ = _inverse3(_line_matrix(line, 0, z))
                volume += 0.125 * abs(det)
    return volume


@njit(cache=True, error_model="numpy")
def _hexahedron_volumes(X, out):
    bx, line = np.empty((8, 3)), np.empty((4, 3, 3))
    for e in range(X.shape[0]):
        out[e] = _volume(X, e, bx, line)


@njit(cache=True, error_model="numpy")  # a collapsed cell: NaN (the guards' to report)
def _characteristic_lengths(X, out):
    """out[e] = volume / largest face area of hexahedron e (faces ``HEX_FACES``, each area
    half the norm of its diagonals' cross product, as ``geometry.quad_areas``)."""
    bx, line = np.empty((8, 3)), np.empty((4, 3, 3))
    for e in range(X.shape[0]):
        largest = 0.0
        for f in range(6):
            a, b, c, d = HEX_FACES[f, 0], HEX_FACES[f, 1], HEX_FACES[f, 2], HEX_FACES[f, 3]
            d1 = X[e, d] - X[e, a]
            d2 = X[e, c] - X[e, b]
            cx = d1[1] * d2[2] - d1[2] * d2[1]
            cy = d1[2] * d2[0] - d1[0] * d2[2]
            cz = d1[0] * d2[1] - d1[1] * d2[0]
            largest = max(largest, 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz))
        out[e] = _volume(X, e, bx, line) / largest


def reference_gradients(point: np.ndarray) -> np.ndarray:
    """Gradients (8, 3) of the trilinear shape functions on [0, 1]^3 at ``point``, DOLFINx vertex
    order: vertex k sits at (k & 1, (k >> 1) & 1, (k >> 2) & 1)."""
    corners = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=float)
    # 1-D factors: corner coordinate 1 -> s, 0 -> 1 - s
    values = np.where(corners == 1, point, 1.0 - point)  # (8, 3)
    slopes = np.where(corners == 1, 1.0, -1.0)
    grads = np.empty((8, 3))
    grads[:, 0] = slopes[:, 0] * values[:, 1] * values[:, 2]
    grads[:, 1] = values[:, 0] * slopes[:, 1] * values[:, 2]
    grads[:, 2] = values[:, 0] * values[:, 1] * slopes[:, 2]
    return grads


def cohesive_pair_time_steps(
    stiffness: float, areas: np.ndarray, m_lower: np.ndarray, m_upper: np.ndarray
) -> np.ndarray:
    """2 / sqrt(k (1/m1 + 1/m2)) for node pairs with interface areas ``areas`` (mm^2), penalty
    ``stiffness`` (N/mm^3, the larger of normal and shear) and masses (tonne)."""
    k = stiffness * areas
    return 2.0 / np.sqrt(k * (1.0 / m_lower + 1.0 / m_upper))
