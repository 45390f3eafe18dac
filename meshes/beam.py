"""Gmsh generators for flat laminated beams and plates, handed to DOLFINx in memory.

Units: mm. The box is [0, length] x [0, width] x [0, thickness], meshed with structured hexahedra
(transfinite + recombine + extrude): ``nx`` x ``ny`` cells in-plane, and through the thickness
either ONE cell (equivalent single layer, ``esl_mesh``) or one cell per layer (``layered_mesh``:
layerwise, a layer being a ply or a group of plies).

Layers separated by a *split* interface get their own nodes on that interface (two coincident node
sets, where cohesive elements go); other layers share their interface nodes.

Face groups, by name (``BeamMesh.facets(name)``):
  x0, x1, y0, y1        the ends (x = 0, x = length) and sides (y = 0, y = width)
  bottom, top           z = 0 and z = thickness
  x0_layer{k}, ...      the same faces restricted to layer k (0 = bottom layer), so that one arm
                        of a layered beam can be pulled or clamped on its own
  bottom_layer{k},      the bottom (z = layer_z[k]) and top (z = layer_z[k + 1]) surface of layer
  top_layer{k}          k. bottom_layer0 is ``bottom`` and top_layer{n-1} is ``top`` (same tag).
                        Across a split boundary k, top_layer{k} and bottom_layer{k + 1} are two
                        coincident surfaces with their own facets and tags (both exterior facets
                        of the DOLFINx mesh: integrate them with ``ds``). Across a non-split
                        boundary they are ONE surface of interior facets carrying one tag, shared
                        by both names (integrate with ``dS``): a facet has one tag in DOLFINx.

Parallel: a mesh with more than one layer is distributed by columns (``columnar_partitioner``):
all cells above one in-plane cell, i.e. every cell of one column, live on the same rank, so that
a cohesive element (a cell and the cell right above it, which share no node across a split
boundary) is complete on one rank. A single-layer mesh uses the DOLFINx default partitioner,
unless its cells do not all cost the same (``cost``: an adaptive model refined from the start
under an insert film): then it too is cut into patches, of equal cost.

Every hexahedron comes out of DOLFINx with its reference zeta axis along +z (vertices 0-3 on its
bottom face, 4-7 on its top face, in the order of the reference cell): the layered integration
of ``fenics_adaptive.element.solid_shell`` relies on it, so the generator checks it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import dolfinx
import dolfinx.io.gmsh
import gmsh
import numpy as np
from dolfinx.cpp.graph import AdjacencyList_int32
from mpi4py import MPI

from fenics_adaptive.errors import shared_errors

SIDES = ("x0", "x1", "y0", "y1")


@dataclass
class BeamMesh:
    mesh: dolfinx.mesh.Mesh
    cell_tags: dolfinx.mesh.MeshTags  # value = layer index + 1
    facet_tags: dolfinx.mesh.MeshTags
    face_tags: dict[str, tuple[int, ...]]  # face-group name -> facet tag values
    length: float
    width: float
    layer_z: np.ndarray  # z of the layer boundaries, bottom to top
    split: tuple[bool, ...] = field(default=())  # per inner layer boundary: own nodes each side?

    @property
    def n_layers(self) -> int:
        return len(self.layer_z) - 1

    @property
    def thickness(self) -> float:
        return float(self.layer_z[-1] - self.layer_z[0])

    def facets(self, name: str) -> np.ndarray:
        """Local indices of the facets of a face group (sorted, unique)."""
        if name not in self.face_tags:
            raise KeyError(f"unknown face group {name!r}; known: {', '.join(self.face_names)}")
        return np.unique(
            np.concatenate([self.facet_tags.find(tag) for tag in self.face_tags[name]])
        ).astype(np.int32)

    @property
    def face_names(self) -> list[str]:
        return list(self.face_tags)


def _facet_tag(layer: int, face: str) -> int:
    """Facet tag of the physical group of ``face`` (a side, ``bottom`` or ``top``) of ``layer``."""
    return 100 * (layer + 1) + ("x0", "x1", "y0", "y1", "bottom", "top").index(face)


def _layer_surface_tags(split: Sequence[bool]) -> dict[str, int]:
    """Facet tag of ``bottom_layer{k}`` and ``top_layer{k}`` for each layer k. A non-split inner
    boundary k is one surface: ``bottom_layer{k + 1}`` takes the tag of ``top_layer{k}``."""
    tags = {}
    for k in range(len(split) + 1):
        shared = k > 0 and not split[k - 1]
        tags[f"bottom_layer{k}"] = _facet_tag(k - 1, "top") if shared else _facet_tag(k, "bottom")
        tags[f"top_layer{k}"] = _facet_tag(k, "top")
    return tags


def _rectangle(length: float, width: float, z: float, nx: int, ny: int) -> int:
    geo = gmsh.model.geo
    p = [
        geo.addPoint(0.0, 0.0, z),
        geo.addPoint(length, 0.0, z),
        geo.addPoint(length, width, z),
        geo.addPoint(0.0, width, z),
    ]
    lines = [geo.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
    for line, n in zip(lines, (nx, ny, nx, ny), strict=True):
        geo.mesh.setTransfiniteCurve(line, n + 1)
    surface = geo.addPlaneSurface([geo.addCurveLoop(lines)])
    geo.mesh.setTransfiniteSurface(surface)
    geo.mesh.setRecombine(2, surface)
    return surface


def layered_mesh(
    comm: MPI.Comm,
    length: float,
    width: float,
    nx: int,
    ny: int,
    layer_thicknesses: Sequence[float],
    split: Sequence[bool] | None = None,
    cost: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> BeamMesh:
    """Layered hexahedral box: one cell per layer through the thickness. ``split[k]`` says whether
    the boundary between layer k and k + 1 has its own nodes on each side. ``cost(x, y)``: the
    cost per step of a cell at in-plane centroid (x, y) mm, when the cells do not all cost the
    same (an adaptive model's cells refined from the start); on several ranks the mesh is
    then cut into patches of equal cost (``columnar_partitioner``), also with one layer."""
    for name, value in (("length", length), ("width", width)):
        if not value > 0:
            raise ValueError(f"mesh.{name}: must be > 0 mm (got {value})")
    for name, value in (("nx", nx), ("ny", ny)):
        if int(value) != value or value < 1:
            raise ValueError(f"mesh.{name}: must be an integer >= 1 (got {value})")
    thicknesses = [float(t) for t in layer_thicknesses]
    if not thicknesses or min(thicknesses) <= 0:
        raise ValueError(f"mesh layers: thicknesses must be > 0 mm (got {thicknesses})")
    split = tuple(
        bool(s) for s in (split if split is not None else [False] * (len(thicknesses) - 1))
    )
    if len(split) != len(thicknesses) - 1:
        raise ValueError("mesh layers: need one split flag per inner layer boundary")
    layer_z = np.concatenate([[0.0], np.cumsum(thicknesses)])

    started_gmsh = not gmsh.isInitialized()
    if started_gmsh:
        gmsh.initialize(interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("fenics_adaptive_beam")
    try:
        partitioner = None
        nodes = None
        # Gmsh meshes on rank 0 only: a failure there must reach every rank before the
        # collective hand-over to DOLFINx
        with shared_errors(comm):
            if comm.rank == 0:
                _build_layers(length, width, nx, ny, thicknesses, split, layer_z)
                if len(thicknesses) > 1 or cost is not None:
                    nodes = dolfinx.io.gmsh.extract_geometry(gmsh.model)
        if len(thicknesses) > 1 or cost is not None:
            partitioner = columnar_partitioner(nodes, 1e-6 * min(length / nx, width / ny), cost)
        mesh_data = dolfinx.io.gmsh.model_to_mesh(
            gmsh.model, comm, 0, gdim=3, partitioner=partitioner
        )
    finally:
        gmsh.model.remove()
        if started_gmsh:
            gmsh.finalize()

    face_tags: dict[str, tuple[int, ...]] = {}
    n_layers = len(thicknesses)
    for face in SIDES:
        face_tags[face] = tuple(_facet_tag(k, face) for k in range(n_layers))
    face_tags["bottom"] = (_facet_tag(0, "bottom"),)
    face_tags["top"] = (_facet_tag(n_layers - 1, "top"),)
    for k in range(n_layers):
        for face in SIDES:
            face_tags[f"{face}_layer{k}"] = (_facet_tag(k, face),)
    for name, tag in _layer_surface_tags(split).items():
        face_tags[name] = (tag,)
    beam = BeamMesh(
        mesh=mesh_data.mesh,
        cell_tags=mesh_data.cell_tags,
        facet_tags=mesh_data.facet_tags,
        face_tags=face_tags,
        length=float(length),
        width=float(width),
        layer_z=layer_z,
        split=split,
    )
    with shared_errors(comm):  # each rank checks its own cells
        _check_orientation(beam)
    return beam


def esl_mesh(
    comm: MPI.Comm, length: float, width: float, nx: int, ny: int, thickness: float
) -> BeamMesh:
    """Equivalent single layer: one hexahedron through the whole laminate thickness."""
    return layered_mesh(comm, length, width, nx, ny, [thickness])


def _build_layers(length, width, nx, ny, thicknesses, split, layer_z) -> None:
    geo = gmsh.model.geo
    volumes, laterals, bottoms, tops = [], [], [], []
    # Gmsh merges coincident geometry, so a layer above a split interface starts from a copy of
    # the interface lifted by `gap`; its nodes are put back onto the interface after meshing.
    gap = 1e-3 * min(thicknesses)
    lifted = []
    top_surface = None
    for k in range(len(thicknesses)):
        if k == 0 or split[k - 1]:
            z0 = layer_z[k] + (gap if k > 0 else 0.0)
            base = _rectangle(length, width, z0, nx, ny)
            if k > 0:
                lifted.append((base, layer_z[k]))
        else:
            base = top_surface
            z0 = layer_z[k]
        out = geo.extrude(
            [(2, base)], 0.0, 0.0, layer_z[k + 1] - z0, numElements=[1], recombine=True
        )
        top_surface = out[0][1]
        volumes.append(out[1][1])
        laterals.append([dim_tag[1] for dim_tag in out[2:]])
        bottoms.append(base)
        tops.append(top_surface)
    geo.synchronize()

    model = gmsh.model
    tol = 1e-9 * max(length, width, layer_z[-1])
    for k, volume in enumerate(volumes):
        model.addPhysicalGroup(3, [volume], k + 1, name=f"layer{k}")
        by_face = {face: [] for face in SIDES}
        for surface in laterals[k]:
            x0, y0, _, x1, y1, _ = model.getBoundingBox(2, surface)
            if abs(x1 - x0) < tol:
                by_face["x0" if abs(x0) < tol else "x1"].append(surface)
            elif abs(y1 - y0) < tol:
                by_face["y0" if abs(y0) < tol else "y1"].append(surface)
        for face, surfaces in by_face.items():
            if len(surfaces) != 1:
                raise RuntimeError(f"gmsh: layer {k} has {len(surfaces)} surfaces on {face}")
            model.addPhysicalGroup(2, surfaces, _facet_tag(k, face), name=f"{face}_layer{k}")
    # Bottom and top of every layer, one physical group per surface (a non-split boundary is a
    # single surface: the top of the layer below), so that no facet is in two groups.
    n = len(volumes) - 1
    for k in range(n + 1):
        if k == 0 or split[k - 1]:
            name = "bottom" if k == 0 else f"bottom_layer{k}"
            model.addPhysicalGroup(2, [bottoms[k]], _facet_tag(k, "bottom"), name=name)
        name = "top" if k == n else f"top_layer{k}"
        model.addPhysicalGroup(2, [tops[k]], _facet_tag(k, "top"), name=name)
    model.mesh.generate(3)
    for surface, z in lifted:
        tags, coords, _ = model.mesh.getNodes(2, surface, includeBoundary=True)
        for tag, xyz in zip(tags, coords.reshape(-1, 3), strict=True):
            model.mesh.setNode(int(tag), [xyz[0], xyz[1], z], [])


def columnar_partitioner(
    nodes: np.ndarray | None,
    tol: float,
    cost: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> Callable:
    """A DOLFINx cell partitioner that keeps every column of cells on one rank.

    ``nodes`` (n_nodes, 3) are the coordinates the cells' node indices refer to (Gmsh's node
    array, ``dolfinx.io.gmsh.extract_geometry``) on the rank that holds the cells, ``None``
    elsewhere. A column is the set of cells with the same in-plane centroid (x, y), to ``tol``
    mm. The columns are cut into the grid of patches with the shortest cuts
    (``patch_grid``, ``grid_parts``): strips across a long beam, near-square patches on a
    plate, where a rank's halo grows with its patch's perimeter, as the square root of its
    cells (strips of a plate's whole width would keep it at the width whatever the rank
    count). ``cost(x, y)``: what a cell at in-plane centroid (x, y) mm costs per step (in
    unrefined cells, > 0; a column costs the sum of its cells'): the patches then hold equal
    cost instead of equal columns (``grid_parts``). Cells are owned by their rank only: no
    extra ghosts (like ``GhostMode.none``).
    """

    def partition(comm, nparts: int, cell_types, cells) -> AdjacencyList_int32:
        (cell_type,) = cell_types
        if cell_type != dolfinx.mesh.CellType.hexahedron:
            raise RuntimeError(f"columnar partitioner: hexahedra expected, got {cell_type}")
        topology = np.asarray(cells[0]).reshape(-1, 8)
        if len(topology) == 0:
            return AdjacencyList_int32(np.zeros(0, dtype=np.int32))
        if nodes is None:
            raise RuntimeError("columnar partitioner: cells given on a rank without the nodes")
        centroids = nodes[topology, :2].mean(axis=1)
        ix, iy = (_cluster(centroids[:, i], tol) for i in range(2))
        keys, column = np.unique(np.stack([ix, iy], axis=1), axis=0, return_inverse=True)
        column = column.ravel()
        weights = None
        if cost is not None:
            cell_cost = np.asarray(cost(centroids[:, 0], centroids[:, 1]), dtype=np.float64)
            weights = np.bincount(column, weights=cell_cost, minlength=len(keys))
        return AdjacencyList_int32(grid_parts(keys, nparts, weights)[column])

    return partition


def patch_grid(parts: int, nx: float = 1.0, ny: float = 1.0) -> tuple[int, int]:
    """(a, b): ``parts`` = a * b patches, a along x and b along y, of a plate of nx x ny cells
    (or columns): the factorisation whose cuts are shortest, (a - 1) ny + (b - 1) nx (the halo
    of the partition), the squarer of two equal ones. A long beam gets strips, a square plate
    near-square patches."""
    if parts < 1:
        raise ValueError(f"parts must be >= 1, not {parts}")
    pairs = [(a, parts // a) for a in range(1, parts + 1) if parts % a == 0]
    return min(pairs, key=lambda ab: ((ab[0] - 1) * ny + (ab[1] - 1) * nx, abs(ab[0] - ab[1])))


def grid_parts(columns: np.ndarray, parts: int, weights: np.ndarray | None = None) -> np.ndarray:
    """The part (int32) of each column of ``columns`` (n, 2: in-plane x and y index) in the
    ``patch_grid`` of the columns' extent: a slabs along x, each cut into b patches along y.
    Every slab holds the same number of columns to within one, and every patch of a slab
    likewise; with ``weights`` (n,) > 0 (a column's cost) the same weight instead, each cut
    within half a column's weight of its target."""
    if len(columns) == 0:
        return np.zeros(0, dtype=np.int32)
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (len(columns),) or not np.all(weights > 0):
            raise ValueError("grid_parts: one weight > 0 per column")
    nx, ny = columns.max(axis=0) - columns.min(axis=0) + 1
    a, b = patch_grid(parts, nx, ny)
    out = np.empty(len(columns), dtype=np.int32)
    by_x = np.lexsort((columns[:, 1], columns[:, 0]))
    for slab, members in enumerate(_split(by_x, a, weights)):
        by_y = members[np.lexsort((columns[members, 0], columns[members, 1]))]
        for cut, patch in enumerate(_split(by_y, b, weights)):
            out[patch] = slab * b + cut
    return out


def _split(ordered: np.ndarray, parts: int, weights: np.ndarray | None) -> list[np.ndarray]:
    """``ordered`` (indices) in ``parts`` consecutive runs of equal length, or, with
    ``weights``, of equal weight: run k ends at the cut nearest to where the cumulative weight
    reaches (k + 1) / parts of the total (every run keeps at least one index where there are
    enough; with none, all runs are empty)."""
    if weights is None or len(ordered) == 0:
        return np.array_split(ordered, parts)
    cumulative = np.cumsum(weights[ordered])
    targets = cumulative[-1] * np.arange(1, parts) / parts
    # the cut nearest each target, in order, one index apart at least
    cuts = np.searchsorted(cumulative, targets, side="left")
    nearer = (cuts > 0) & (
        np.abs(cumulative[np.maximum(cuts - 1, 0)] - targets) < np.abs(cumulative[cuts] - targets)
    )
    cuts = np.where(nearer, cuts, cuts + 1)
    n = len(ordered)
    for k in range(len(cuts)):  # strictly increasing, within (0, n)
        low = cuts[k - 1] + 1 if k else 1
        cuts[k] = min(max(cuts[k], low), max(n - (len(cuts) - k), low))
    return np.split(ordered, cuts)


def _cluster(values: np.ndarray, tol: float) -> np.ndarray:
    """Index of each value among the distinct values (ascending), values closer than ``tol``
    counting as one."""
    order = np.argsort(values, kind="stable")
    index = np.empty(len(values), dtype=np.int64)
    index[order] = np.concatenate([[0], np.cumsum(np.diff(values[order]) > tol)])
    return index


def _check_orientation(beam: BeamMesh) -> None:
    """Each cell's vertices 4-7 must sit straight above 0-3 (reference zeta = +z), vertex 1 must
    follow vertex 0 in +x-ish and vertex 2 in +y-ish directions (a right-handed cell)."""
    mesh = beam.mesh
    x = mesh.geometry.x
    nodes = mesh.geometry.dofmaps[0]
    n_local = mesh.topology.index_map(3).size_local
    X = x[nodes[:n_local]]
    rise = X[:, 4:, :] - X[:, :4, :]
    in_plane = np.linalg.norm(rise[:, :, :2], axis=2)
    if np.any(rise[:, :, 2] <= 0.0) or np.any(in_plane > 1e-9 * (1.0 + rise[:, :, 2])):
        raise RuntimeError("mesh: hexahedra are not extruded along +z (zeta must be the normal)")
    d_xi = X[:, 1, :] - X[:, 0, :]
    d_eta = X[:, 2, :] - X[:, 0, :]
    if np.any(np.cross(d_xi, d_eta)[:, 2] <= 0.0):
        raise RuntimeError("mesh: hexahedra are not right-handed in the (xi, eta) plane")
