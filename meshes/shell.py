"""Solid shells from a quadrilateral reference surface (``meshes.surface``): each quadrilateral
extruded along the surface normal into one hexahedron through the laminate (equivalent single
layer) or one per layer (layerwise), handed to DOLFINx.

Units: mm.

Normals. The quadrilaterals are first oriented consistently (each pair sharing an edge runs
along it in opposite directions: one side of the surface is "up"); a surface that cannot be
(a Moebius band) or has an edge shared by three quadrilaterals is refused, naming a
quadrilateral. ``outward`` chooses the side: the normals of each connected piece point along it
on average. A node moves through the thickness along the surface's normal where the geometry
(Gmsh's CAD model, or the normals a file written by ``surface.write_surface`` carries) gives
one, elsewhere along the mean of its quadrilaterals' normals; and it moves farther than the
layer's thickness by 1 / cos of the angle between that direction and its quadrilaterals'
normals (their mean), so that each cell keeps the laminate's thickness across its own faces.
At a fold (a hat's corners) that is the mitre, whose offset keeps both faces' thickness; on a
smooth surface meshed coarsely (a tube of 12 cells around) it keeps the faceted wall as thick
as the laminate, which offsets of exactly the thickness along the true normals would thin by
that cosine (3.4 % at 30 degrees per cell, 10 % of its bending stiffness).

Frames. ``direction`` (a vector, or a function of position for tubes: ``axial_direction``,
``hoop_direction``) is the material 1-direction before the ply angle. Each quadrilateral's
node order is turned (cyclically, which keeps its normal) so that its first edge, the cells'
xi direction, is the one closest to ``direction``: the selective (ANS) shear rule acts on the
strain components of the cell's frame (``element.geometry.cell_frames``: 1 = ``direction``
projected on the surface, 3 = the normal), and is exact when xi runs along 1; a structured
mesh along the direction has them aligned, an unstructured one within 45 degrees
(``ShellMesh.misalignment``).

Cells and faces. Layer k's cells carry tag k + 1 and the quadrilateral's cells sit in one
column, kept on one rank (a cohesive element joins a cell and the one above it). Faces, as for
the flat meshes (``meshes.beam``): ``bottom``, ``top``, ``bottom_layer{k}``, ``top_layer{k}``;
the sides are named after the surface's edges: ``x0`` (all layers), ``x0_layer{k}``.
``reference``: the surface given is the laminate's bottom, middle or top.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import basix.ufl
import dolfinx
import numpy as np
from dolfinx.cpp.graph import AdjacencyList_int32
from fenics_adaptive.meshes.beam import BeamMesh, _layer_surface_tags
from fenics_adaptive.meshes.surface import SurfaceMesh
from mpi4py import MPI

from fenics_adaptive.element.geometry import cell_frames, cell_normals, frames_about
from fenics_adaptive.errors import InputError, shared_errors

REFERENCES = ("bottom", "middle", "top")
# the names a side face (an edge group) may have, and those the laminate's faces take
_SIDE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_RESERVED = re.compile(r"(bottom|top)(_layer\d+)?|.*_layer\d+")
# the hexahedron's side facet (DOLFINx reference numbering) over each edge of its quadrilateral
# (edge j runs from quad node j to j + 1; the hexahedron's bottom is quad nodes 0, 1, 3, 2)
_EDGE_FACET = np.array([1, 3, 4, 2], dtype=np.int64)


# A material direction: (points (n, 3), unit normals (n, 3)) -> directions (n, 3), projected on
# the surface afterwards (``element.geometry.frames_about``)
Direction = Callable[[np.ndarray, np.ndarray], np.ndarray]


def axial_direction(axis: Sequence[float]) -> Direction:
    """The material direction along ``axis`` everywhere (a tube's axial direction)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return lambda points, normals: np.broadcast_to(axis, np.shape(points)).copy()


def hoop_direction(axis: Sequence[float]) -> Direction:
    """The material direction around ``axis``: axis x the surface normal (a tube's hoop
    direction; around the profile of a hat or a panel swept along the axis, flanges too)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return lambda points, normals: np.cross(axis, normals)


def toward(vector: Sequence[float]) -> Callable[[np.ndarray], np.ndarray]:
    """The same side everywhere, as ``orient``'s ``outward`` takes it: points (n, 3) ->
    ``vector`` at each."""
    vector = np.asarray(vector, dtype=np.float64)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)) or not np.any(vector):
        raise ValueError(f"mesh.normal: a non-zero vector of 3 numbers (got {vector})")
    return lambda points: np.broadcast_to(vector, np.shape(points)).copy()


def constant_direction(vector: Sequence[float]) -> Direction:
    """A material direction that is the same vector everywhere (projected on the surface by
    ``cell_frames``)."""
    vector = np.asarray(vector, dtype=np.float64)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)) or not np.any(vector):
        raise ValueError(f"mesh.direction: a non-zero vector of 3 numbers (got {vector})")
    return axial_direction(vector)


@dataclass
class ShellMesh(BeamMesh):
    """A layered solid shell on a curved (or flat) reference surface. ``layer_z`` are the
    layer boundaries' positions through the thickness from the laminate's bottom (mm);
    ``length`` and ``width`` the two longest extents of its bounding box (mm).
    ``direction``: the material 1-direction as a function of position."""

    direction: Direction = field(default=None)
    misalignment: float = 0.0  # largest angle (degrees) between a cell's xi and its 1-direction

    def cell_frames(self, X: np.ndarray) -> np.ndarray:
        """(n, 3, 3) frames of cells with vertices X (n, 8, 3): rows the material 1-, 2- and
        3- (normal) directions (``element.geometry.cell_frames``)."""
        return cell_frames(X, self.direction(X.mean(axis=1), cell_normals(X)))


# the least mean cosine between the normals of a connected piece of surface and the side
# ``orient`` is asked to turn them to: below it the direction says no side
SIDE_TOLERANCE = 1.0e-3


def orient(surface: SurfaceMesh, outward: Callable[[np.ndarray], np.ndarray] | None = None):
    """``surface`` with its quadrilaterals turned to one side (module docstring); ``outward``:
    a direction at points (n, 3) -> (n, 3) that each connected piece's normals follow on
    average (None: the first quadrilateral of each piece keeps its order)."""
    quads = surface.quads.copy()
    m = len(quads)
    edge_a = quads.ravel()
    edge_b = np.roll(quads, -1, axis=1).ravel()
    owner = np.repeat(np.arange(m), 4)
    key = np.minimum(edge_a, edge_b) * (len(surface.nodes) + 1) + np.maximum(edge_a, edge_b)
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(key_sorted)])
    if np.any(counts > 2):
        quad = owner[order[starts[np.argmax(counts > 2)]]]
        raise ValueError(
            f"mesh: an edge of quadrilateral {quad} is shared by {counts.max()} "
            "quadrilaterals; a shell surface must be a manifold"
        )
    pairs = [
        (order[s], order[s + 1]) for s, c in zip(starts, counts, strict=True) if c == 2
    ]  # half-edges on one shared edge
    neighbours = [[] for _ in range(m)]
    for e, f in pairs:
        same = edge_a[e] == edge_a[f]  # both run the same way: one quad must be flipped
        neighbours[owner[e]].append((owner[f], same))
        neighbours[owner[f]].append((owner[e], same))
    flip = np.full(m, -1, dtype=np.int64)
    piece = np.full(m, -1, dtype=np.int64)
    n_pieces = 0
    for seed in range(m):
        if flip[seed] >= 0:
            continue
        flip[seed], piece[seed] = 0, n_pieces
        stack = [seed]
        while stack:
            q = stack.pop()
            for r, same in neighbours[q]:
                wanted = flip[q] ^ int(same)
                if flip[r] < 0:
                    flip[r], piece[r] = wanted, n_pieces
                    stack.append(r)
                elif flip[r] != wanted:
                    raise ValueError(
                        f"mesh: quadrilateral {r} cannot be oriented consistently with its "
                        "neighbours (the surface is not orientable, a Moebius band)"
                    )
        n_pieces += 1
    quads[flip == 1] = quads[flip == 1][:, ::-1]
    oriented = SurfaceMesh(surface.nodes, quads, surface.edges, surface.axis, surface.normals)
    if outward is not None:
        normals = oriented.quad_normals()
        toward_side = outward(surface.nodes[quads].mean(axis=1))
        toward_side = toward_side / np.linalg.norm(toward_side, axis=1, keepdims=True)
        along = np.einsum("qi,qi->q", normals, toward_side)
        mean = np.bincount(piece, weights=along, minlength=n_pieces) / np.bincount(
            piece, minlength=n_pieces
        )
        if np.any(np.abs(mean) < SIDE_TOLERANCE):  # it says no side: refuse, not guess
            at = int(np.flatnonzero(np.abs(mean) < SIDE_TOLERANCE)[0])
            first = int(np.flatnonzero(piece == at)[0])
            raise ValueError(
                f"mesh.normal: the direction given is perpendicular to the surface (its "
                f"cosine with the normals averages {mean[at]:.1e} over the piece of "
                f"quadrilateral {first}): it does not say which side the normals point to; "
                "give a vector along the normals you want"
            )
        turn = mean < 0.0
        quads[turn[piece]] = quads[turn[piece]][:, ::-1]
    return SurfaceMesh(surface.nodes, quads, surface.edges, surface.axis, surface.normals)


def align(surface: SurfaceMesh, direction: Direction) -> tuple[SurfaceMesh, float]:
    """(surface, largest misalignment in degrees): each quadrilateral's nodes turned
    cyclically so that its first edge is the one pointing most along its material axis 1
    (``direction`` projected on it by the frames' own rule, ``frames_about``)."""
    X = surface.nodes[surface.quads]  # (m, 4, 3)
    normals = surface.quad_normals()
    axis = frames_about(normals, direction(X.mean(axis=1), normals))[:, 0]
    edges = np.roll(X, -1, axis=1) - X
    edges /= np.linalg.norm(edges, axis=2)[:, :, None]
    cosines = np.einsum("mji,mi->mj", edges, axis)
    first = np.argmax(cosines, axis=1)
    turned = np.take_along_axis(surface.quads, (first[:, None] + np.arange(4)) % 4, axis=1)
    worst = float(np.degrees(np.arccos(np.clip(cosines.max(axis=1).min(), -1.0, 1.0))))
    return SurfaceMesh(surface.nodes, turned, surface.edges, surface.axis, surface.normals), worst


def nodal_offsets(surface: SurfaceMesh) -> np.ndarray:
    """(n, 3) the direction each node moves along through the thickness, scaled so that a unit
    offset along it moves the node a unit distance off its quadrilaterals' planes (on their
    mean): the direction is the geometry's normal where known, else the mean of the
    quadrilaterals' normals (module docstring)."""
    normals = surface.quad_normals()
    n_nodes = len(surface.nodes)
    at_node = np.repeat(normals, 4, axis=0)  # each quadrilateral's normal at its four nodes
    summed = np.zeros((n_nodes, 3))
    np.add.at(summed, surface.quads.ravel(), at_node)
    direction = summed / np.linalg.norm(summed, axis=1)[:, None]
    exact = np.all(np.isfinite(surface.normals), axis=1)
    side = np.sign(np.einsum("ni,ni->n", surface.normals[exact], direction[exact]))
    direction[exact] = side[:, None] * surface.normals[exact]
    cosines = np.einsum("ni,ni->n", direction[surface.quads.ravel()], at_node)
    least = np.ones(n_nodes)
    np.minimum.at(least, surface.quads.ravel(), cosines)
    if np.any(least <= 0.1):
        node = int(np.argmin(least))
        raise ValueError(
            f"mesh: the quadrilaterals around node {node} at {surface.nodes[node].tolist()} "
            "fold back on each other; no direction through the thickness serves them all"
        )
    mean = np.bincount(surface.quads.ravel(), weights=cosines, minlength=n_nodes)
    mean /= np.bincount(surface.quads.ravel(), minlength=n_nodes)
    return direction / mean[:, None]


def shell_mesh(
    comm: MPI.Comm,
    surface: SurfaceMesh | None,
    layer_thicknesses: Sequence[float],
    split: Sequence[bool] | None = None,
    reference: str = "middle",
    direction: Direction | None = None,
    outward: Callable[[np.ndarray], np.ndarray] | None = None,
) -> ShellMesh:
    """The solid shell of ``surface`` (given on rank 0; None elsewhere): one hexahedron per
    quadrilateral and layer (``layer_thicknesses``, mm, bottom to top), ``split[k]``: layers k
    and k + 1 get their own nodes on their common boundary (for cohesive elements). The
    surface is the laminate's ``reference`` ("bottom", "middle" or "top") surface;
    ``direction``: the material 1-direction (default: global x projected on the surface, or
    global z where x is normal to it, as Abaqus does); ``outward``: the side the normals point
    to (``orient``). Collective."""
    if reference not in REFERENCES:
        raise ValueError(f"mesh.reference: one of {', '.join(REFERENCES)} (got {reference!r})")
    thicknesses = [float(t) for t in layer_thicknesses]
    if not thicknesses or min(thicknesses) <= 0 or not all(map(math.isfinite, thicknesses)):
        raise ValueError(f"mesh layers: thicknesses must be > 0 mm (got {thicknesses})")
    n_layers = len(thicknesses)
    split = tuple(bool(s) for s in (split if split is not None else [False] * (n_layers - 1)))
    if len(split) != n_layers - 1:
        raise ValueError("mesh layers: need one split flag per inner layer boundary")
    direction = direction if direction is not None else constant_direction([1.0, 0.0, 0.0])
    layer_z = np.concatenate([[0.0], np.cumsum(thicknesses)])
    shift = {"bottom": 0.0, "middle": 0.5, "top": 1.0}[reference] * layer_z[-1]

    cells = np.zeros((0, 8), dtype=np.int64)
    x = np.zeros((0, 3))
    edge_of_side = np.zeros((0, 4), dtype=np.int64)  # per quad edge: its named group or -1
    names: list[str] = []
    misalignment = 0.0
    size = np.zeros(2)
    with shared_errors(comm):  # Gmsh's surface is on rank 0; its error reaches every rank
        if comm.rank == 0:
            if surface is None:
                raise ValueError("shell_mesh: the surface must be given on rank 0")
            try:
                surface = orient(surface, outward)
                surface, misalignment = align(surface, direction)
                x, cells = _extrude(surface, layer_z - shift, split)
                _check_cells(x[cells], n_layers)
                names, edge_of_side = _side_groups(surface)
            except ValueError as error:  # the user's geometry: an input error on every rank
                key, _, problem = str(error).partition(": ")
                if not key.startswith("mesh"):
                    raise
                raise InputError(key, problem) from error
            extents = np.sort(np.ptp(surface.nodes, axis=0))[::-1]
            size = extents[:2]
    names = comm.bcast(names, root=0)
    misalignment, size = comm.bcast((misalignment, size), root=0)
    quad_centres = x[cells].mean(axis=1)[::n_layers] if len(cells) else np.zeros((0, 3))
    element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
    mesh = dolfinx.mesh.create_mesh(
        comm, cells, element, x, partitioner=_column_partitioner(quad_centres, n_layers)
    )
    mesh.topology.create_connectivity(3, 2)
    mesh.topology.create_connectivity(2, 3)
    # each rank learns the side groups of its own cells' quadrilaterals
    edge_of_side = comm.bcast(edge_of_side, root=0)
    n_owned = mesh.topology.index_map(3).size_local
    original = np.asarray(mesh.topology.original_cell_index)[:n_owned]
    quad, layer = original // n_layers, original % n_layers
    cell_tags = dolfinx.mesh.meshtags(
        mesh, 3, np.arange(n_owned, dtype=np.int32), (layer + 1).astype(np.int32)
    )
    surfaces = _layer_surface_tags(split)
    cell_facets = mesh.topology.connectivity(3, 2).array.reshape(-1, 6)[:n_owned]
    facets, values = [], []
    for k in range(n_layers):
        mine = np.flatnonzero(layer == k)
        facets += [cell_facets[mine, 0], cell_facets[mine, 5]]
        values += [
            np.full(len(mine), surfaces[f"bottom_layer{k}"]),
            np.full(len(mine), surfaces[f"top_layer{k}"]),
        ]
    sides = edge_of_side[quad]  # (n_owned, 4)
    cell, edge = np.nonzero(sides >= 0)
    facets.append(cell_facets[cell, _EDGE_FACET[edge]])
    values.append(_side_tag(sides[cell, edge], layer[cell]))
    facets, values = np.concatenate(facets), np.concatenate(values).astype(np.int32)
    facets, first = np.unique(facets, return_index=True)
    facet_tags = dolfinx.mesh.meshtags(mesh, 2, facets.astype(np.int32), values[first])
    face_tags: dict[str, tuple[int, ...]] = {
        "bottom": (surfaces["bottom_layer0"],),
        "top": (surfaces[f"top_layer{n_layers - 1}"],),
    }
    for name, tag in surfaces.items():
        face_tags[name] = (tag,)
    for g, name in enumerate(names):
        face_tags[name] = tuple(int(_side_tag(g, k)) for k in range(n_layers))
        for k in range(n_layers):
            face_tags[f"{name}_layer{k}"] = (int(_side_tag(g, k)),)
    return ShellMesh(
        mesh=mesh,
        cell_tags=cell_tags,
        facet_tags=facet_tags,
        face_tags=face_tags,
        length=float(size[0]),
        width=float(size[1]),
        layer_z=layer_z,
        split=split,
        direction=direction,
        misalignment=misalignment,
    )


def _side_tag(group, layer):
    """Facet tag of side group ``group`` on layer ``layer`` (clear of the layer surfaces')."""
    return 10_000 * (np.asarray(group) + 1) + np.asarray(layer) + 1


def _extrude(surface: SurfaceMesh, levels: np.ndarray, split: tuple[bool, ...]):
    """(x (N, 3), cells (m n_layers, 8)): the nodes at every level through the thickness (two
    copies at a split boundary) and the hexahedra, quadrilateral by quadrilateral, bottom
    layer first."""
    offsets = nodal_offsets(surface)
    n = len(surface.nodes)
    sets = []  # (level, copy): the node sets, bottom to top
    below_of_layer, above_of_layer = [], []
    for k, z in enumerate(levels):
        if 0 < k < len(levels) - 1 and split[k - 1]:
            below_of_layer.append(len(sets))  # top of layer k - 1
            sets.append(z)
            above_of_layer.append(len(sets))  # bottom of layer k
            sets.append(z)
        else:
            if k > 0:
                below_of_layer.append(len(sets))
            if k < len(levels) - 1:
                above_of_layer.append(len(sets))
            sets.append(z)
    x = np.concatenate([surface.nodes + z * offsets for z in sets])
    a, b, c, d = surface.quads.T
    bottom_face = np.stack([a, b, d, c], axis=1)  # tensor order
    cells = np.empty((len(surface.quads), len(levels) - 1, 8), dtype=np.int64)
    for k in range(len(levels) - 1):
        cells[:, k, :4] = bottom_face + above_of_layer[k] * n
        cells[:, k, 4:] = bottom_face + below_of_layer[k] * n
    return x, cells.reshape(-1, 8)


def _check_cells(X: np.ndarray, n_layers: int) -> None:
    """Every hexahedron's Jacobian positive at its eight corners; else the quadrilateral and
    layer of the first that is not (too thick for the surface's curvature, or distorted)."""
    for c in range(8):
        g = [X[:, _neighbour(c, axis, 1)] - X[:, _neighbour(c, axis, 0)] for axis in range(3)]
        det = np.einsum("ni,ni->n", np.cross(g[0], g[1]), g[2])
        if np.any(det <= 0.0):
            cell = int(np.argmax(det <= 0.0))
            raise ValueError(
                f"mesh: the cell of quadrilateral {cell // n_layers}, layer {cell % n_layers}, "
                "is inverted at a corner: the laminate is too thick for the surface's "
                "curvature there, or the quadrilateral is distorted"
            )


def _neighbour(corner: int, axis: int, high: int) -> int:
    """The vertex of a hexahedron's edge along ``axis`` through ``corner`` at that axis'
    coordinate ``high``."""
    return (corner & ~(1 << axis)) | (high << axis)


def check_side_names(names: Sequence[str]) -> None:
    """Raise ValueError for an edge group name a side face cannot take: bottom, top and the
    names with _layer<k> are the laminate's own faces, and a name is letters, digits and _
    (a face of a config, joined to others by &)."""
    for name in names:
        if not _SIDE_NAME.fullmatch(name) or _RESERVED.fullmatch(name):
            raise ValueError(
                f"mesh: an edge group may not be called {name!r}: bottom, top and the names "
                "with _layer<k> are the laminate's own faces; use letters, digits and _"
            )


def _side_groups(surface: SurfaceMesh) -> tuple[list[str], np.ndarray]:
    """(group names, (m, 4) group index of each quadrilateral edge or -1)."""
    names = sorted(surface.edges)
    check_side_names(names)
    n = len(surface.nodes) + 1
    lookup: dict[int, int] = {}
    for g, name in enumerate(names):
        pairs = surface.edges[name]
        for key in (np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(*pairs.T)).tolist():
            if lookup.setdefault(key, g) != g:
                raise ValueError(
                    f"mesh: an edge is in both edge groups {names[lookup[key]]!r} and "
                    f"{name!r}; a face of the solid shell takes one name"
                )
    a = surface.quads.ravel()
    b = np.roll(surface.quads, -1, axis=1).ravel()
    keys = (np.minimum(a, b) * n + np.maximum(a, b)).tolist()
    groups = np.array([lookup.get(key, -1) for key in keys], dtype=np.int64)
    return names, groups.reshape(-1, 4)


def _column_partitioner(quad_centres: np.ndarray, n_layers: int) -> Callable:
    """A DOLFINx cell partitioner keeping each quadrilateral's column on one rank: the
    columns cut into compact patches of equal count by recursive coordinate bisection of
    their centres (``quad_centres``, given where the cells are, in their order)."""

    def partition(comm, nparts: int, cell_types, cells) -> AdjacencyList_int32:
        n_cells = len(np.asarray(cells[0])) // 8
        if n_cells == 0:
            return AdjacencyList_int32(np.zeros(0, dtype=np.int32))
        if n_cells != len(quad_centres) * n_layers:
            raise RuntimeError("shell partitioner: cells given on a rank without their columns")
        part = np.zeros(len(quad_centres), dtype=np.int32)
        _bisect(quad_centres, np.arange(len(quad_centres)), 0, nparts, part)
        return AdjacencyList_int32(np.repeat(part, n_layers))

    return partition


def _bisect(points: np.ndarray, members: np.ndarray, first: int, parts: int, out) -> None:
    """Recursive coordinate bisection: ``members`` into ``parts`` parts numbered from
    ``first``, each cut across the longest extent, in proportion to the parts each side."""
    if parts == 1 or len(members) == 0:
        out[members] = first
        return
    left = parts // 2
    axis = int(np.argmax(np.ptp(points[members], axis=0)))
    ordered = members[np.argsort(points[members, axis], kind="stable")]
    cut = round(len(ordered) * left / parts)
    _bisect(points, ordered[:cut], first, left, out)
    _bisect(points, ordered[cut:], first + left, parts - left, out)
