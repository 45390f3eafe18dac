"""Quadrilateral reference surfaces of shells: generated with Gmsh's OCC kernel (tube,
cylindrical panel, hat section, plate with a hole) or read from a user's ``.msh``/``.geo`` file
or Gmsh model. ``meshes.shell`` extrudes them into solid shells.

Units: mm. A surface is plain arrays (``SurfaceMesh``): node coordinates, quadrilaterals (four
node indices each, in Gmsh's order: around the quadrilateral, so the normal is (x1 - x0) x
(x3 - x0) by the right-hand rule), and named boundary edges, one group per physical group of
curves (``x0``, ``x1`` ...), which become the named side faces of the solid shell.

Generated geometry, axis along x (the beams' length direction):

- ``tube``: the cylinder y^2 + z^2 = R^2, 0 <= x <= length; edges ``x0``, ``x1``.
- ``panel``: the part of that cylinder at angles theta (from +z towards +y, degrees) in
  [start, start + angle]; edges ``x0``, ``x1``, ``theta0``, ``theta1``.
- ``hat``: a hat channel, its profile in the y-z plane (flanges at z = 0, crown at z = height,
  webs vertical), extruded along x; edges ``x0``, ``x1``, ``flange0``, ``flange1``.
- ``plate_with_hole``: [0, length] x [0, width] at z = 0 less a centred hole of radius r;
  edges ``x0``, ``x1``, ``y0``, ``y1``, ``hole``. Its quadrilaterals are unstructured
  (Gmsh's Blossom recombination), the others structured.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gmsh
import numpy as np

# Gmsh element types
_LINE, _TRIANGLE, _QUAD = 1, 2, 3


@dataclass
class SurfaceMesh:
    """A reference surface of quadrilaterals (mm): ``nodes`` (n, 3), ``quads`` (m, 4) node
    indices around each quadrilateral, ``edges`` name -> (k, 2) node index pairs of that named
    boundary curve, ``axis``: a named direction of the part (a tube's axis) or None."""

    nodes: np.ndarray
    quads: np.ndarray
    edges: dict[str, np.ndarray] = field(default_factory=dict)
    axis: np.ndarray | None = None
    # (n, 3) the geometry's unit normal at each node where the CAD model gives one that is
    # the same on every surface through the node; NaN elsewhere (a fold, or a mesh file)
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.nodes = np.asarray(self.nodes, dtype=np.float64).reshape(-1, 3)
        self.quads = np.asarray(self.quads, dtype=np.int64).reshape(-1, 4)
        self.edges = {
            k: np.asarray(v, dtype=np.int64).reshape(-1, 2) for k, v in self.edges.items()
        }
        if self.normals is None:
            self.normals = np.full(self.nodes.shape, np.nan)
        if len(self.quads) == 0:
            raise ValueError("surface mesh: no quadrilaterals")
        if self.quads.min() < 0 or self.quads.max() >= len(self.nodes):
            raise ValueError("surface mesh: a quadrilateral refers to a node that does not exist")
        ordered = np.sort(self.quads, axis=1)
        repeats = np.flatnonzero((ordered[:, 1:] == ordered[:, :-1]).any(axis=1))
        if len(repeats):
            raise ValueError(f"surface mesh: quadrilateral {int(repeats[0])} repeats a node")

    def quad_normals(self) -> np.ndarray:
        """(m, 3) unit normals of the quadrilaterals at their centres (the cross product of
        their diagonals)."""
        X = self.nodes[self.quads]
        n = np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 1])
        length = np.linalg.norm(n, axis=1)
        if np.any(length == 0.0):
            raise ValueError(f"mesh: quadrilateral {int(np.argmin(length))} has no area")
        return n / length[:, None]

    def characteristic_size(self) -> float:
        """The longest extent of the surface's bounding box (mm)."""
        return float(np.ptp(self.nodes, axis=0).max())


def from_gmsh(surface: str | None = None, axis: np.ndarray | None = None) -> SurfaceMesh:
    """The quadrilaterals of the current Gmsh model (meshed already), of the surfaces of the
    physical group named ``surface`` (all surfaces if None), and its physical groups of curves
    as named edges. Raises ValueError for triangles or second-order elements, naming them."""
    model = gmsh.model
    if surface is None:
        entities = [tag for _, tag in model.getEntities(2)]
    else:
        groups = {model.getPhysicalName(2, tag): tag for _, tag in model.getPhysicalGroups(2)}
        if surface not in groups:
            known = ", ".join(sorted(name for name in groups if name)) or "none"
            raise ValueError(f"mesh.surface: no physical surface {surface!r} (known: {known})")
        entities = list(model.getEntitiesForPhysicalGroup(2, groups[surface]))
    quads = []
    for entity in entities:
        types, _, element_nodes = model.mesh.getElements(2, entity)
        for kind, nodes in zip(types, element_nodes, strict=True):
            if kind == _QUAD:
                quads.append(np.asarray(nodes, dtype=np.int64).reshape(-1, 4))
            elif kind == _TRIANGLE:
                raise ValueError(
                    f"mesh: surface {entity} has triangles; solid shells need quadrilaterals "
                    "(recombine the surface: Recombine Surface{...}; or Mesh.RecombineAll = 1)"
                )
            else:
                name = model.mesh.getElementProperties(kind)[0]
                raise ValueError(f"mesh: surface {entity} has {name} elements; use 4-node quads")
    if not quads:
        raise ValueError("mesh: the surface has no quadrilaterals (was it meshed?)")
    quads = np.concatenate(quads)
    tags, coords, _ = model.mesh.getNodes()
    position = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    position[tags.astype(np.int64)] = np.arange(len(tags))
    coords = coords.reshape(-1, 3)
    used = np.unique(quads)
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    edges = {}
    for _, group in model.getPhysicalGroups(1):
        name = model.getPhysicalName(1, group) or f"curve{group}"
        pairs = []
        for entity in model.getEntitiesForPhysicalGroup(1, group):
            types, _, element_nodes = model.mesh.getElements(1, entity)
            for kind, nodes in zip(types, element_nodes, strict=True):
                if kind == _LINE:
                    pairs.append(np.asarray(nodes, dtype=np.int64).reshape(-1, 2))
        if pairs:
            pairs = index[np.concatenate(pairs)]
            edges[name] = pairs[np.all(pairs >= 0, axis=1)]
    normals = _file_normals(index, len(used))
    if normals is None:
        normals = _cad_normals(entities, index, len(used))
    return SurfaceMesh(coords[position[used]], index[quads], edges, axis, normals)


def _cad_normals(entities: list[int], index: np.ndarray, n_nodes: int) -> np.ndarray:
    """(n_nodes, 3) the unit normal of the geometry at each node (``SurfaceMesh.normals``):
    NaN where a surface has no parametrisation (a discrete one, read from a mesh file) or two
    surfaces through the node disagree by more than a degree."""
    normals = np.full((n_nodes, 3), np.nan)
    seen = np.zeros(n_nodes, dtype=bool)
    unknown = np.zeros(n_nodes, dtype=bool)
    for entity in entities:
        tags, _, uv = gmsh.model.mesh.getNodes(
            2, entity, includeBoundary=True, returnParametricCoord=True
        )
        nodes = index[tags.astype(np.int64)]
        if len(uv) != 2 * len(tags) or gmsh.model.getType(2, entity) == "Discrete surface":
            unknown[nodes] = True
            continue
        n = np.asarray(gmsh.model.getNormal(entity, uv)).reshape(-1, 3)
        n /= np.linalg.norm(n, axis=1)[:, None]
        # a second surface through a node must agree up to sign (orientation comes later)
        again = seen[nodes]
        agree = np.abs(np.einsum("ni,ni->n", normals[nodes[again]], n[again]))
        unknown[nodes[again][agree < np.cos(np.radians(1.0))]] = True
        normals[nodes[~again]] = n[~again]
        seen[nodes] = True
    normals[unknown | ~seen] = np.nan
    return normals


# the last surface read from a file, by the file's identity (``read_surface``): a run reads
# its file when its config is checked and again when its mesh is built
_LAST_READ: dict[tuple, SurfaceMesh] = {}


def read_surface(path: str | Path, surface: str | None = None) -> SurfaceMesh:
    """The quadrilateral surface of a Gmsh ``.msh`` file, or of a ``.geo`` script (meshed in
    two dimensions if it has no mesh yet), restricted to the physical surface ``surface``. The
    last surface read is kept: the same file (path, size and modification time) and surface
    again gives a copy of it without Gmsh."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"mesh.file: {str(path)!r} is not a file")
    if path.suffix.lower() not in (".msh", ".geo"):
        raise ValueError(f"mesh.file: {path.name!r} is neither a .msh nor a .geo file")
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns, surface)
    if key not in _LAST_READ:
        with _gmsh_model("fenics_adaptive_surface"):
            try:
                gmsh.open(str(path))
            except Exception as error:
                raise ValueError(f"mesh.file: gmsh cannot read {path.name!r}: {error}") from error
            if len(gmsh.model.mesh.getElements(2)[0]) == 0:
                gmsh.model.mesh.generate(2)
            read = from_gmsh(surface)
        _LAST_READ.clear()
        _LAST_READ[key] = read
    return copy.deepcopy(_LAST_READ[key])  # the caller may change its arrays


class _gmsh_model:
    """A Gmsh model of its own for the block (Gmsh started and stopped if nobody else has)."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        self.started = not gmsh.isInitialized()
        if self.started:
            gmsh.initialize(interruptible=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(self.name)
        return gmsh.model

    def __exit__(self, *exc):
        gmsh.model.remove()
        if self.started:
            gmsh.finalize()
        return False


def _positive(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"mesh.{name}: must be > 0 mm (got {value})")
    return float(value)


def _count(name: str, value: int, least: int = 1) -> int:
    if int(value) != value or value < least:
        raise ValueError(f"mesh.{name}: must be an integer >= {least} (got {value})")
    return int(value)


def _sweep(
    profile: Callable[[], list[tuple[int, int]]],
    length: float,
    n_along: int,
    names: dict[str, Callable[[list[int], list[int]], list[int]]],
    axis: np.ndarray | None,
) -> SurfaceMesh:
    """A profile of curves in the plane x = 0 (``profile()`` builds them in OCC and returns
    (curve, elements) pairs) swept to x = length: structured quadrilaterals."""
    with _gmsh_model("fenics_adaptive_sweep"):
        occ = gmsh.model.occ
        curves = profile()
        occ.synchronize()
        for curve, n in curves:
            gmsh.model.mesh.setTransfiniteCurve(curve, n + 1)
        out = occ.extrude([(1, c) for c, _ in curves], length, 0, 0, [n_along], recombine=True)
        occ.synchronize()
        tops = [tag for dim, tag in out if dim == 1]
        surfaces = [tag for dim, tag in out if dim == 2]
        starts = [c for c, _ in curves]
        # extrude returns, per input curve, its swept copy, the surface and the side curves
        for name, pick in names.items():
            gmsh.model.addPhysicalGroup(1, pick(starts, tops), name=name)
        gmsh.model.addPhysicalGroup(2, surfaces, name="shell")
        gmsh.model.mesh.generate(2)
        return from_gmsh("shell", axis)


def _curves_at(x: float, tol: float) -> list[int]:
    """The model's curves lying in the plane at ``x``."""
    out = []
    for _, tag in gmsh.model.getEntities(1):
        x0, _, _, x1, _, _ = gmsh.model.getBoundingBox(1, tag)
        if abs(x0 - x) < tol and abs(x1 - x) < tol:
            out.append(tag)
    return out


def _lines_along_x(y: float, z: float, tol: float) -> list[int]:
    """The model's straight curves along x at (y, z)."""
    out = []
    for _, tag in gmsh.model.getEntities(1):
        _, y0, z0, _, y1, z1 = gmsh.model.getBoundingBox(1, tag)
        if max(abs(y0 - y), abs(y1 - y), abs(z0 - z), abs(z1 - z)) < tol:
            out.append(tag)
    return out


def tube(radius: float, length: float, n_around: int, n_along: int) -> SurfaceMesh:
    """The cylinder y^2 + z^2 = radius^2 (mm), 0 <= x <= length: ``n_around`` x ``n_along``
    structured quadrilaterals, edges ``x0`` and ``x1``."""
    radius, length = _positive("radius", radius), _positive("length", length)
    n_around, n_along = _count("n_around", n_around, 3), _count("n_along", n_along)
    tol = 1e-6 * max(radius, length)

    def profile():
        circle = gmsh.model.occ.addCircle(0, 0, 0, radius, zAxis=[1, 0, 0])
        return [(circle, n_around)]

    names = {
        "x0": lambda starts, tops: _curves_at(0.0, tol),
        "x1": lambda starts, tops: _curves_at(length, tol),
    }
    return _sweep(profile, length, n_along, names, np.array([1.0, 0.0, 0.0]))


def panel(
    radius: float,
    length: float,
    angle: float,
    n_around: int,
    n_along: int,
    start: float | None = None,
) -> SurfaceMesh:
    """The part of the cylinder y^2 + z^2 = radius^2 (mm), 0 <= x <= length, at angles theta
    (degrees from +z towards +y) in [start, start + angle] (``start`` defaults to -angle / 2,
    a panel symmetric about the crown): ``n_around`` x ``n_along`` structured
    quadrilaterals; edges ``x0``, ``x1``, ``theta0`` (at start) and ``theta1``."""
    radius, length = _positive("radius", radius), _positive("length", length)
    if not (math.isfinite(angle) and 0 < angle < 360):
        raise ValueError(f"mesh.angle: must be in (0, 360) degrees (got {angle})")
    n_around, n_along = _count("n_around", n_around), _count("n_along", n_along)
    start = -0.5 * angle if start is None else float(start)
    tol = 1e-6 * max(radius, length)
    # a circle arc is the shorter one between its ends: from 180 degrees on, two arcs
    pieces = 2 if angle >= 180.0 else 1
    if n_around < pieces:
        raise ValueError(f"mesh.n_around: a panel of {angle} degrees needs at least 2 cells")
    ends = [math.radians(start + angle * k / pieces) for k in range(pieces + 1)]
    points = [(radius * math.sin(a), radius * math.cos(a)) for a in ends]
    cells = [n_around // pieces + (k < n_around % pieces) for k in range(pieces)]

    def profile():
        occ = gmsh.model.occ
        p = [occ.addPoint(0, y, z) for y, z in points]
        centre = occ.addPoint(0, 0, 0)
        return [(occ.addCircleArc(p[k], centre, p[k + 1]), cells[k]) for k in range(pieces)]

    names = {
        "x0": lambda starts, tops: _curves_at(0.0, tol),
        "x1": lambda starts, tops: _curves_at(length, tol),
        "theta0": lambda starts, tops: _lines_along_x(*points[0], tol),
        "theta1": lambda starts, tops: _lines_along_x(*points[-1], tol),
    }
    return _sweep(profile, length, n_along, names, np.array([1.0, 0.0, 0.0]))


def hat(
    length: float, width: float, height: float, flange: float, size: float, n_along: int
) -> SurfaceMesh:
    """A hat channel (mm): crown ``width`` wide at z = ``height``, vertical webs, flanges
    ``flange`` wide at z = 0, swept along x over ``length`` with ``n_along`` cells; each straight
    piece of the profile cut into cells of about ``size``. Edges ``x0``, ``x1``, ``flange0``
    (the free edge at y < 0) and ``flange1``."""
    length, width = _positive("length", length), _positive("width", width)
    height, flange = _positive("height", height), _positive("flange", flange)
    size, n_along = _positive("size", size), _count("n_along", n_along)
    tol = 1e-6 * max(length, width, height, flange)
    half = 0.5 * width
    corners = [
        (-half - flange, 0.0),
        (-half, 0.0),
        (-half, height),
        (half, height),
        (half, 0.0),
        (half + flange, 0.0),
    ]

    def profile():
        occ = gmsh.model.occ
        p = [occ.addPoint(0, y, z) for y, z in corners]
        out = []
        for a, b, (ya, za), (yb, zb) in zip(p, p[1:], corners, corners[1:], strict=False):
            pieces = max(1, round(math.hypot(yb - ya, zb - za) / size))
            out.append((occ.addLine(a, b), pieces))
        return out

    names = {
        "x0": lambda starts, tops: _curves_at(0.0, tol),
        "x1": lambda starts, tops: _curves_at(length, tol),
        "flange0": lambda starts, tops: _lines_along_x(*corners[0], tol),
        "flange1": lambda starts, tops: _lines_along_x(*corners[-1], tol),
    }
    return _sweep(profile, length, n_along, names, np.array([1.0, 0.0, 0.0]))


def plate_with_hole(length: float, width: float, hole_radius: float, size: float) -> SurfaceMesh:
    """[0, length] x [0, width] (mm) at z = 0 less a centred hole of ``hole_radius``, in
    unstructured quadrilaterals of about ``size`` (all quadrilaterals: Gmsh's Blossom full-quad
    recombination). Edges ``x0``, ``x1``, ``y0``, ``y1`` and ``hole``."""
    length, width = _positive("length", length), _positive("width", width)
    hole_radius, size = _positive("hole_radius", hole_radius), _positive("size", size)
    if 2 * hole_radius >= min(length, width):
        raise ValueError(
            f"mesh.hole_radius: a hole of radius {hole_radius} mm does not fit in the "
            f"{length} x {width} mm plate"
        )
    tol = 1e-6 * max(length, width)
    with _gmsh_model("fenics_adaptive_plate_with_hole"):
        occ = gmsh.model.occ
        plate = occ.addRectangle(0, 0, 0, length, width)
        hole = occ.addDisk(0.5 * length, 0.5 * width, 0, hole_radius, hole_radius)
        occ.cut([(2, plate)], [(2, hole)])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.Algorithm", 8)
        gmsh.option.setNumber("Mesh.RecombinationAlgorithm", 3)  # Blossom full-quad
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
        sides = {"x0": [], "x1": [], "y0": [], "y1": [], "hole": []}
        for _, tag in gmsh.model.getEntities(1):
            x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(1, tag)
            if abs(x1 - x0) < tol:
                sides["x0" if abs(x0) < tol else "x1"].append(tag)
            elif abs(y1 - y0) < tol:
                sides["y0" if abs(y0) < tol else "y1"].append(tag)
            else:
                sides["hole"].append(tag)
        for name, tags in sides.items():
            gmsh.model.addPhysicalGroup(1, tags, name=name)
        surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
        gmsh.model.addPhysicalGroup(2, surfaces, name="shell")
        gmsh.model.mesh.generate(2)
        return from_gmsh("shell")


GENERATORS = {
    "tube": tube,
    "panel": panel,
    "hat": hat,
    "plate_with_hole": plate_with_hole,
}


def shell_surface(kind: str, sizes: dict, file: str | None = None, surface: str | None = None):
    """The reference surface of a shell ``kind`` (a generator's name with its ``sizes``, or
    "file": the quadrilaterals of ``file``, physical surface ``surface``)."""
    if kind == "file":
        return read_surface(file, surface)
    return GENERATORS[kind](**sizes)


def write_surface(surface: SurfaceMesh, path: str | Path) -> None:
    """Write ``surface`` as a binary Gmsh ``.msh`` file (exact coordinates): its quadrilaterals
    on one surface, physical group "shell", each named edge a physical curve, and the normals
    the geometry gave (``SurfaceMesh.normals``, where known) as node data named "normal",
    which ``read_surface`` takes back: the file gives the same solid shell as the surface."""
    path = Path(path)
    with _gmsh_model("fenics_adaptive_write"):
        model = gmsh.model
        tags = np.arange(1, len(surface.nodes) + 1)
        shell = model.addDiscreteEntity(2)
        model.mesh.addNodes(2, shell, tags, surface.nodes.ravel())
        model.mesh.addElementsByType(shell, _QUAD, [], (surface.quads + 1).ravel())
        model.addPhysicalGroup(2, [shell], name="shell")
        for name, pairs in sorted(surface.edges.items()):
            curve = model.addDiscreteEntity(1)
            model.mesh.addElementsByType(curve, _LINE, [], (pairs + 1).ravel())
            model.addPhysicalGroup(1, [curve], name=name)
        gmsh.option.setNumber("Mesh.Binary", 1)
        gmsh.write(str(path))
        known = np.all(np.isfinite(surface.normals), axis=1)
        if np.any(known):
            view = gmsh.view.add("normal")
            gmsh.view.addHomogeneousModelData(
                view, 0, model.getCurrent(), "NodeData", tags[known], surface.normals[known].ravel()
            )
            gmsh.option.setNumber("PostProcessing.Binary", 1)
            gmsh.option.setNumber("PostProcessing.SaveMesh", 0)  # the mesh is there already
            gmsh.view.write(view, str(path), append=True)


def _file_normals(index: np.ndarray, n_nodes: int) -> np.ndarray | None:
    """The "normal" node data of a file ``write_surface`` wrote, by node (NaN where it has
    none), or None if the file has none."""
    for view in gmsh.view.getTags():
        if gmsh.option.getString(f"View[{gmsh.view.getIndex(view)}].Name") != "normal":
            continue
        kind, tags, data, _, components = gmsh.view.getHomogeneousModelData(view, 0)
        if kind != "NodeData" or components != 3:
            continue
        normals = np.full((n_nodes, 3), np.nan)
        tags = np.asarray(tags, dtype=np.int64)
        inside = tags < len(index)
        normals[index[tags[inside]]] = np.asarray(data).reshape(-1, 3)[inside]
        return normals
    return None
