"""Geometric helpers of the hexahedral (sub)elements and their faces: the one copy of each.

Units: mm.

Vertex order: DOLFINx's tensor order, vertex k at (k & 1, (k >> 1) & 1, (k >> 2) & 1) of the
reference cube; a quadrilateral face (4 vertices) in the same order (vertices 0 and 3, 1 and 2
opposite); a hexahedron's bottom face is vertices 0-3, its top face 4-7.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def quad_areas(X: np.ndarray) -> np.ndarray:
    """Areas (mm^2, shape X.shape[:-2]) of planar quadrilaterals with vertices X (..., 4, 3) in
    tensor order: half the norm of the cross product of the diagonals."""
    d1 = X[..., 3, :] - X[..., 0, :]
    d2 = X[..., 2, :] - X[..., 1, :]
    return 0.5 * np.linalg.norm(np.cross(d1, d2), axis=-1)


def thickness_weight(fractions: np.ndarray, level, below, above):
    """Where thickness fraction ``fractions[level]`` lies between ``fractions[below]`` (0) and
    ``fractions[above]`` (1): the weight of the upper face in a linear interpolation through
    the thickness. ``level``, ``below``, ``above``: ply-boundary indices (ints or arrays)."""
    return (fractions[level] - fractions[below]) / (fractions[above] - fractions[below])


def slab_vertices(
    bottom: np.ndarray, top: np.ndarray, w_lower: np.ndarray, w_upper: np.ndarray
) -> np.ndarray:
    """Vertices (n, 8, 3) of the slabs between thickness weights ``w_lower`` and ``w_upper``
    (n,) of hexahedra with bottom and top faces ``bottom``, ``top`` (n, 4, 3), vertices linearly
    interpolated along the hexahedra's vertical edges."""
    lower = bottom + w_lower[:, None, None] * (top - bottom)
    upper = bottom + w_upper[:, None, None] * (top - bottom)
    return np.concatenate([lower, upper], axis=1)


# DOLFINx's (Basix's) reference facets of a hexahedron, vertices in tensor order: facet 0 is the
# bottom face, 5 the top face, 1-4 the sides (y = 0, x = 0, x = 1, y = 1 of the reference cube)
HEX_FACETS = np.array(
    [[0, 1, 2, 3], [0, 1, 4, 5], [0, 2, 4, 6], [1, 3, 5, 7], [2, 3, 6, 7], [4, 5, 6, 7]],
    dtype=np.int64,
)
HEX_SIDE_FACETS = np.array([1, 2, 3, 4], dtype=np.int64)

_GAUSS_2 = 0.5 * (1.0 + np.array([-1.0, 1.0]) / np.sqrt(3.0))  # on [0, 1], weights 1/2 each


def quad_traction_integrals(
    X: np.ndarray,
    outward: np.ndarray,
    traction: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> np.ndarray:
    """Work-equivalent nodal forces (k, 4, 3) N of a traction over quadrilaterals with vertices
    X (k, 4, 3) in tensor order: the integral of N_i t(x) over each, by 2 x 2 Gauss points
    (exact for planar faces and a traction linear in x). ``outward`` (k, 3): a vector pointing
    out of the body at each face (the unit normals are turned to agree with it);
    ``traction(points, normals)``: (m, 3) N/mm^2 at points (m, 3) mm with outward unit normals
    (m, 3)."""
    out = np.zeros(X.shape)
    for s in _GAUSS_2:
        for r in _GAUSS_2:
            N = np.array([(1 - s) * (1 - r), s * (1 - r), (1 - s) * r, s * r])
            dN_ds = np.array([-(1 - r), 1 - r, -r, r])
            dN_dr = np.array([-(1 - s), -s, 1 - s, s])
            ts = np.einsum("k,...kj->...j", dN_ds, X)
            tr = np.einsum("k,...kj->...j", dN_dr, X)
            normal = np.cross(ts, tr)
            area = np.linalg.norm(normal, axis=-1)  # per unit (s, r) area
            normal /= np.where(area > 0.0, area, 1.0)[:, None]
            normal *= np.where(np.einsum("kj,kj->k", normal, outward) < 0.0, -1.0, 1.0)[:, None]
            t = traction(np.einsum("k,...kj->...j", N, X), normal)
            out += 0.25 * (area[:, None] * t)[:, None, :] * N[None, :, None]
    return out
