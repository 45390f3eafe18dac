"""``[mesh]`` of a shell: the kinds Gmsh generates and a user's surface file, as the config
gives them (standard library only; ``fenics_adaptive.meshes`` builds them).

Units: mm, degrees.

Each kind has its own keys (``KIND_KEYS``); a key of another kind is refused, naming the kind
it belongs to, so that a tube's ``nx`` is not silently ignored. The side faces a shell's
loads and supports name are its edges (``ShellShape.edges``): fixed for the generated kinds,
the physical curves of a file (read when the config is).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fenics_adaptive.errors import InputError
from fenics_adaptive.settings.kinds import MaterialAxis, MeshKind, SurfaceReference

# the keys each kind needs (required) and may have (optional)
KIND_KEYS: dict[MeshKind, tuple[tuple[str, ...], tuple[str, ...]]] = {
    MeshKind.PLATE: (("length", "width", "nx", "ny"), ()),
    MeshKind.TUBE: (("radius", "length", "n_around", "n_along"), ()),
    MeshKind.PANEL: (("radius", "length", "angle", "n_around", "n_along"), ("start",)),
    MeshKind.HAT: (("length", "width", "height", "flange", "size", "n_along"), ()),
    MeshKind.PLATE_WITH_HOLE: (("length", "width", "hole_radius", "size"), ()),
    MeshKind.FILE: (("file",), ("surface", "normal")),
}
# the keys of every shell kind (not of the plate)
SHELL_KEYS = ("reference", "direction")
AXIS_KINDS = (MeshKind.TUBE, MeshKind.PANEL, MeshKind.HAT)
EDGES = {
    MeshKind.TUBE: ("x0", "x1"),
    MeshKind.PANEL: ("x0", "x1", "theta0", "theta1"),
    MeshKind.HAT: ("x0", "x1", "flange0", "flange1"),
    MeshKind.PLATE_WITH_HOLE: ("x0", "x1", "y0", "y1", "hole"),
}


@dataclass(frozen=True)
class ShellShape:
    """A shell's ``[mesh]``: its ``kind``, the kind's ``sizes`` (name -> value, as
    ``meshes.surface``'s generator of that name takes them), the laminate ``reference`` surface,
    the material 1-direction (``direction`` vector, or ``orientation`` along/around the axis),
    the ``normal`` side hint (files), the ``file`` (absolute path) and ``surface`` (physical
    group), its ``edges`` (side face names) and ``quads`` (its quadrilaterals, estimated for a
    plate with a hole)."""

    kind: MeshKind
    sizes: tuple[tuple[str, float], ...]
    reference: SurfaceReference
    direction: tuple[float, float, float] | None
    orientation: MaterialAxis | None
    normal: tuple[float, float, float] | None
    file: str | None
    surface: str | None
    edges: tuple[str, ...]
    quads: int

    def size(self, name: str) -> float:
        return dict(self.sizes)[name]


def shell_shape(table, kind: MeshKind, source: str) -> ShellShape:
    """The ``[mesh]`` ``table`` (a config ``_Table``) of a shell of ``kind``; ``source``: the
    config's path (a relative ``file`` is relative to its folder) or "<memory>"."""
    required, optional = KIND_KEYS[kind]
    sizes = {}
    for name in required + optional:
        if name in ("file", "surface", "normal"):
            continue
        if name not in required and not table.has(name):
            continue
        if not table.has(name):
            raise InputError(table.key(name), f'missing (kind = "{kind}" needs it)')
        number = table.integer(name) if name.startswith("n_") else table.number(name)
        if name == "n_around" and kind == MeshKind.TUBE and number < 3:
            raise InputError(
                table.key(name), f"a tube needs at least 3 cells around (got {number})"
            )
        sizes[name] = number
    direction = table.numbers("direction")
    orientation = table.choice("orientation") if table.has("orientation") else None
    if orientation is not None and kind not in AXIS_KINDS:
        raise InputError(
            table.key("orientation"), f"a {kind} has no axis: give direction = [x, y, z] instead"
        )
    if orientation is not None and direction is not None:
        raise InputError(table.key("orientation"), "give either orientation or direction")
    if direction is not None and not any(direction):
        raise InputError(table.key("direction"), "must not be the zero vector")
    normal = table.numbers("normal") if kind == MeshKind.FILE else None
    if normal is not None and not any(normal):
        raise InputError(table.key("normal"), "must not be the zero vector")
    file = surface = None
    if kind == MeshKind.FILE:
        file = _resolve(table.string("file"), source)
        surface = table.string("surface") if table.has("surface") else None
        edges, quads = _file_summary(table, file, surface)
    else:
        edges, quads = EDGES[kind], _estimated_quads(kind, sizes)
    if kind == MeshKind.PANEL and sizes.get("start") is None:
        sizes["start"] = -0.5 * sizes["angle"]
    if kind == MeshKind.PLATE_WITH_HOLE and 2 * sizes["hole_radius"] >= min(
        sizes["length"], sizes["width"]
    ):
        raise InputError(
            table.key("hole_radius"),
            f"a hole of radius {sizes['hole_radius']:g} mm does not fit in the "
            f"{sizes['length']:g} x {sizes['width']:g} mm plate",
        )
    return ShellShape(
        kind=kind,
        sizes=tuple(sizes.items()),
        reference=table.choice("reference"),
        direction=direction,
        orientation=orientation,
        normal=normal,
        file=file,
        surface=surface,
        edges=tuple(edges),
        quads=quads,
    )


def refuse_other_keys(table, kind: MeshKind) -> None:
    """A key of [mesh] that ``kind`` does not take is refused, naming the kinds that do."""
    required, optional = KIND_KEYS[kind]
    mine = set(required + optional) | {"kind", "layers", "partition", "rebalance"}
    if kind != MeshKind.PLATE:
        mine |= set(SHELL_KEYS) | ({"orientation"} if kind in AXIS_KINDS else set())
    for name in table.schema.names:
        if name in mine or not table.has(name):
            continue
        owners = [str(k) for k, (r, o) in KIND_KEYS.items() if name in r + o]
        if name in SHELL_KEYS:
            owners = ["the shells"]
        if name == "orientation":
            owners = [str(k) for k in AXIS_KINDS]
        raise InputError(
            table.key(name), f'not a key of kind = "{kind}" (it belongs to {", ".join(owners)})'
        )


def _resolve(path: str, source: str) -> str:
    """``path`` made absolute: relative to the config file's folder (or the working folder for
    a config given in memory)."""
    candidate = Path(path).expanduser()
    if not candidate.is_absolute() and not source.startswith("<"):
        candidate = Path(source).resolve().parent / candidate
    return str(candidate.resolve())


def _file_summary(table, file: str, surface: str | None) -> tuple[tuple[str, ...], int]:
    """(edge names, quadrilaterals) of a surface file; InputError naming ``mesh.file`` (or
    ``mesh.surface``) if Gmsh cannot give a quadrilateral surface from it."""
    from fenics_adaptive.meshes.shell import check_side_names  # Gmsh: only for this kind
    from fenics_adaptive.meshes.surface import read_surface

    try:
        mesh = read_surface(file, surface)
        check_side_names(sorted(mesh.edges))
    except ValueError as error:
        text = str(error)
        key = "surface" if text.startswith("mesh.surface") else "file"
        raise InputError(table.key(key), text.split(": ", 1)[-1]) from error
    return tuple(sorted(mesh.edges)), len(mesh.quads)


def _estimated_quads(kind: MeshKind, sizes: dict) -> int:
    """The quadrilaterals of a generated kind (an estimate for the unstructured plate with a
    hole)."""
    if kind in (MeshKind.TUBE, MeshKind.PANEL):
        return sizes["n_around"] * sizes["n_along"]
    if kind == MeshKind.HAT:
        pieces = (
            2 * max(1, round(sizes["flange"] / sizes["size"]))
            + 2 * max(1, round(sizes["height"] / sizes["size"]))
            + max(1, round(sizes["width"] / sizes["size"]))
        )
        return pieces * sizes["n_along"]
    area = sizes["length"] * sizes["width"] - 3.14159 * sizes["hole_radius"] ** 2
    return max(1, round(area / sizes["size"] ** 2))
