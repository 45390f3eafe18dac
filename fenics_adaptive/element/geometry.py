"""Geometric helpers of the hexahedral (sub)elements and their faces: the one copy of each.

Units: mm.

Vertex order: DOLFINx's tensor order, vertex k at (k & 1, (k >> 1) & 1, (k >> 2) & 1) of the
reference cube; a quadrilateral face (4 vertices) in the same order (vertices 0 and 3, 1 and 2
opposite); a hexahedron's bottom face is vertices 0-3, its top face 4-7.
"""

from __future__ import annotations

import math
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


# Abaqus' rule for a shell's default local 1-direction: global x projected on the surface,
# unless x is within 0.1 degree of the normal, then global z projected
_NORMAL_TO_DIRECTION = math.sin(math.radians(0.1))


def cell_normals(X: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals of the mid-surfaces of hexahedra X (n, 8, 3) at their centres,
    d x / d xi x d x / d eta."""
    X = np.asarray(X, dtype=np.float64)
    along_xi = (X[:, 1::2] - X[:, 0::2]).mean(axis=1)
    along_eta = (X[:, [2, 3, 6, 7]] - X[:, [0, 1, 4, 5]]).mean(axis=1)
    e3 = np.cross(along_xi, along_eta)
    return e3 / np.linalg.norm(e3, axis=1)[:, None]


def frames_about(normals: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n, 3, 3) orthonormal frames, rows (e1, e2, e3): e3 the unit ``normals`` (n, 3), e1
    ``direction`` (n, 3) projected on the plane normal to e3 (where it lies within 0.1 degree
    of e3: global z projected, or global x if that too, as Abaqus' default shell directions),
    e2 = e3 x e1. The one rule of a curved shell's material frames (``cell_frames``, and the
    cells' turning in ``meshes.shell.align``)."""
    e3 = np.asarray(normals, dtype=np.float64)
    d = np.broadcast_to(np.asarray(direction, dtype=np.float64), e3.shape)
    e1 = _projected(d, e3)
    for fallback in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]):
        bad = np.linalg.norm(e1, axis=1) <= _NORMAL_TO_DIRECTION
        if not np.any(bad):
            break
        e1[bad] = _projected(np.broadcast_to(fallback, (int(bad.sum()), 3)), e3[bad])
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return np.stack([e1, np.cross(e3, e1), e3], axis=1)


def cell_frames(X: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n, 3, 3) frames of hexahedra with vertices X (n, 8, 3), rows (e1, e2, e3): e3 the
    normal of the cell's mid-surface at its centre (``cell_normals``), e1 ``direction`` (n,
    3) projected on the surface (``frames_about``). A flat cell of the meshes of
    ``meshes.beam`` with ``direction`` along x has the identity."""
    return frames_about(cell_normals(X), direction)


def _projected(d: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``d`` (n, 3) normalised (where not zero) with its component along the unit ``normal``
    (n, 3) removed."""
    length = np.linalg.norm(d, axis=1)[:, None]
    d = d / np.where(length > 0.0, length, 1.0)
    return d - np.einsum("ni,ni->n", d, normal)[:, None] * normal
