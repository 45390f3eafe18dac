"""Stable time step of the central-difference scheme.

Units: mm, s, tonne, N.

Solids: dt <= L_e / c per (sub)element, L_e = volume / largest face area, c = the fastest
dilatational wave speed of its plies. Cohesive node pairs (nodes 1, 2 with masses m1, m2 joined by
a penalty spring k = K A_node, A_node the node's share of the interface area):
dt <= 2 / sqrt(k (1/m1 + 1/m2)). The caller applies the safety factor.
"""

from __future__ import annotations

import numpy as np

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element.geometry import quad_areas

# Local vertex lists of the six faces of a reference hexahedron (DOLFINx numbering), each face
# in tensor order (``geometry.quad_areas``).
HEX_FACES = np.array(
    [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 4, 5], [2, 3, 6, 7], [0, 2, 4, 6], [1, 3, 5, 7]]
)


# Cells per block of the vectorised geometry below: bounds its temporaries (about 1.5 kB per
# cell) to some 12 MiB, where one block of 160 000 cells took 200 MiB at every stable-step check.
BLOCK = 8192


def characteristic_lengths(X: np.ndarray) -> np.ndarray:
    """Volume / largest face area of hexahedra with vertex coordinates X (n, 8, 3)."""
    out = np.empty(len(X))
    for start in range(0, len(X), BLOCK):
        block = X[start : start + BLOCK]
        areas = quad_areas(block[:, HEX_FACES, :])  # (n, 6)
        out[start : start + BLOCK] = hexahedron_volumes(block) / areas.max(axis=1)
    return out


def hexahedron_volumes(X: np.ndarray) -> np.ndarray:
    """Exact volumes of trilinear hexahedra (2x2x2 Gauss on det J)."""
    g = solid_shell.GAUSS_2
    volume = np.zeros(len(X))
    for a in g:
        for b in g:
            for c in g:
                dN = reference_gradients(np.array([a, b, c]))  # (8, 3)
                J = np.einsum("nki,kj->nij", X, dN)  # (n, 3, 3): dx_i / dX_j
                volume += 0.125 * np.abs(np.linalg.det(J))
    return volume


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
