"""Geometric helpers of the hexahedral (sub)elements and their faces: the one copy of each.

Units: mm.

Vertex order: DOLFINx's tensor order, vertex k at (k & 1, (k >> 1) & 1, (k >> 2) & 1) of the
reference cube; a quadrilateral face (4 vertices) in the same order (vertices 0 and 3, 1 and 2
opposite); a hexahedron's bottom face is vertices 0-3, its top face 4-7.
"""

from __future__ import annotations

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
