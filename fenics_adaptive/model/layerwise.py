"""The layerwise (LW) reference model: which nodes each cohesive element joins.

Units: N, mm, s, tonne (coordinates in mm).

An LW reference model meshes a laminate with ONE plain solid (hexahedral) element layer per
sublaminate (``fenics_adaptive.meshes.beam.layered_mesh``: mesh layer k carries sublaminate k, k = 0
at the bottom). Where the boundary k between mesh layers k and k + 1 is *split*
(``BeamMesh.split[k]``) the mesh has two coincident node sets there, joined by 8-node cohesive
elements (``fenics_adaptive.materials.cohesive``) that may delaminate; a non-split boundary shares
its nodes and stays perfectly bonded. It is the model the adaptive ESL element must reproduce when
refined everywhere from the start.

Conventions. One cohesive element per cell of layer k below a split boundary k: its lower face
is that cell's top face (DOLFINx local vertices 4-7), its upper face the bottom face (vertices
0-3) of the cell right above it in layer k + 1. Element nodes are ordered as
``cohesive.cohesive_element_force`` wants them: node a = 0..3 is lower-cell vertex 4 + a, at face
coordinates (a & 1, (a >> 1) & 1) (the lower cell's top-face tensor order), and node a + 4 is the
upper node at the same position as node a, matched by coordinates (the two cells may order
their vertices differently in the plane). Nodes are local node (block) indices of the P1 vector
space V (owned or ghost; DOF of component i = 3 node + i).

Parallel: each rank lists the elements of its OWNED lower cells. The cell above must be on the
same rank (``layered_mesh`` partitions by columns, which guarantees it); if not, this module
says so instead of silently dropping elements.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np

from fenics_adaptive.meshes.beam import BeamMesh

LOWER_FACE = np.arange(4, 8)  # local vertices of a hexahedron's top face, tensor order
UPPER_FACE = np.arange(0, 4)  # its bottom face


@dataclass(frozen=True)
class CohesivePairs:
    """The cohesive elements of the LW model on this rank (one row each)."""

    nodes: np.ndarray  # (n, 8) int32: lower face 0-3, upper face 4-7 (node a + 4 above node a)
    boundary: np.ndarray  # (n,) int32: split layer boundary k (between mesh layers k and k + 1)
    cell: np.ndarray  # (n,) int32: local index of the lower cell (owned, in layer k)
    upper_cell: np.ndarray  # (n,) int32: local index of the cell above it (layer k + 1)

    def __len__(self) -> int:
        return len(self.cell)


def cohesive_pairs(beam: BeamMesh, V: dolfinx.fem.FunctionSpace) -> CohesivePairs:
    """The cohesive elements joining the owned cells of every layer below a split boundary to the
    cells above them; see the module docstring for the node order. ``V`` is the P1 vector space
    on ``beam.mesh``. Raises RuntimeError if a partner cell or a coincident node is not on this
    rank or the mesh is not split where ``beam.split`` says."""
    if V.mesh is not beam.mesh:
        raise ValueError("cohesive_pairs: V is not a space on beam.mesh")
    if V.dofmap.list.shape[1] != 8:
        raise ValueError("cohesive_pairs: V must be the P1 (8 nodes per hexahedron) space")
    topology = beam.mesh.topology
    n_owned = topology.index_map(3).size_local
    n_cells = n_owned + topology.index_map(3).num_ghosts
    layer = np.full(n_cells, -1, dtype=np.int64)
    layer[beam.cell_tags.indices] = beam.cell_tags.values - 1
    cell_nodes = V.dofmap.list  # (cells, 8): node i of a P1 cell sits at its vertex i
    x = V.tabulate_dof_coordinates()
    tol = 1e-6 * float(np.min(np.diff(beam.layer_z)))

    rows = []
    for k in np.flatnonzero(beam.split):
        lower = np.flatnonzero(layer[:n_owned] == k).astype(np.int32)
        if len(lower) == 0:
            continue
        upper = _cells_above(lower, np.flatnonzero(layer == k + 1), cell_nodes, x, tol, k)
        lower_nodes = cell_nodes[lower][:, LOWER_FACE]
        upper_nodes = _match_nodes(lower_nodes, cell_nodes[upper][:, UPPER_FACE], x, tol, k)
        if np.any(lower_nodes == upper_nodes):
            raise RuntimeError(
                f"cohesive_pairs: layer boundary {k} is marked split but the mesh shares its "
                "nodes there (no coincident node sets)"
            )
        nodes = np.hstack([lower_nodes, upper_nodes]).astype(np.int32)
        rows.append((nodes, np.full(len(lower), k, dtype=np.int32), lower, upper))
    if not rows:
        empty = np.zeros(0, dtype=np.int32)
        return CohesivePairs(np.zeros((0, 8), dtype=np.int32), empty, empty, empty)
    nodes, boundary, cell, upper_cell = (np.concatenate(c) for c in zip(*rows, strict=True))
    return CohesivePairs(nodes, boundary, cell, upper_cell.astype(np.int32))


def _face_keys(cells: np.ndarray, face: np.ndarray, cell_nodes, x, tol) -> np.ndarray:
    """Integer keys (len(cells), 3) of the face centroids, rounded to ``tol`` mm."""
    centroids = x[cell_nodes[cells][:, face]].mean(axis=1)
    return np.round(centroids / tol).astype(np.int64)


def _cells_above(lower, candidates, cell_nodes, x, tol, k) -> np.ndarray:
    """For each lower cell, the candidate cell whose bottom face is its top face."""
    lower_keys = _face_keys(lower, LOWER_FACE, cell_nodes, x, tol)
    upper_keys = _face_keys(candidates, UPPER_FACE, cell_nodes, x, tol)
    _, group = np.unique(np.vstack([upper_keys, lower_keys]), axis=0, return_inverse=True)
    group = group.ravel()
    upper_group, lower_group = group[: len(candidates)], group[len(candidates) :]
    if np.any(np.bincount(upper_group) > 1):
        raise RuntimeError(f"cohesive_pairs: two cells of layer {k + 1} share a bottom face")
    where = np.full(group.max() + 1, -1, dtype=np.int64)
    where[upper_group] = candidates
    above = where[lower_group]
    if np.any(above < 0):
        c = lower[np.argmax(above < 0)]
        centre = x[cell_nodes[c][LOWER_FACE]].mean(axis=0)
        raise RuntimeError(
            f"cohesive_pairs: no cell of layer {k + 1} on this rank above cell {c} of layer {k} "
            f"(top face centre {np.round(centre, 6).tolist()} mm); the cohesive element across "
            f"split boundary {k} needs both cells on one rank (partition the mesh by columns)"
        )
    return above.astype(np.int32)


def _match_nodes(lower_nodes, upper_nodes, x, tol, k) -> np.ndarray:
    """Reorder each row of ``upper_nodes`` (n, 4) so that node a sits on ``lower_nodes[:, a]``."""
    distance = np.linalg.norm(
        x[lower_nodes][:, :, None, :] - x[upper_nodes][:, None, :, :], axis=3
    )  # (n, 4 lower, 4 upper)
    nearest = np.argmin(distance, axis=2)
    gap = np.take_along_axis(distance, nearest[:, :, None], axis=2)[:, :, 0]
    if np.any(gap > tol) or np.any(np.sort(nearest, axis=1) != np.arange(4)):
        i = int(np.argmax(gap.max(axis=1)))
        raise RuntimeError(
            f"cohesive_pairs: across split boundary {k}, node {int(lower_nodes[i, 0])} and its "
            f"face have no coincident node set above them (largest gap {gap[i].max():.3g} mm)"
        )
    return np.take_along_axis(upper_nodes, nearest, axis=1)
