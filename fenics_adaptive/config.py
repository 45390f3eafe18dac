"""Run configuration: a TOML file, checked completely before anything runs.

Units: N, mm, s, tonne (stress MPa, density tonne/mm^3, energy mJ). Every config file says so in
its header. Every problem is reported as one line naming the key, e.g.
``mesh.nx: must be an integer >= 1 (got 0)``; unknown keys are errors, never ignored.

Sections (see demos/*.toml for complete examples):
  [model]        kind = "esl" | "layerwise"; points_per_ply (1 or 2); kinematics = "small"
                 (default) | "finite" (total Lagrangian: large rotations; no ply_damage)
  [mesh]         length, width (mm), nx, ny (cells in-plane); layers = [plies per mesh layer]
                 for a layerwise model (default: one layer per ply)
  [materials.NAME]  E1, E2, G12, nu12, nu23, rho, optional G23
  [laminate]     material + ply_thickness + angles (bottom to top), or plies = [{material,
                 angle, thickness}, ...]
  [[clamp]]      face                         all components held at zero
  [[prescribed]] face, component, displacement (mm) or velocity (mm/s), time curve
  [[load]]       face, force = [Fx, Fy, Fz] (N, total over the face), time curve
  [solver]       end_time, safety_factor, time_step (optional, forced), mass_damping (1/s)
  [output]       interval (s between history rows), fields_interval (s, optional),
                 checkpoint_interval (steps, optional), displacement_face, reaction_face,
                 component
  [impactor]     shape ("sphere" | "cylinder", axis along y), radius (mm), mass (tonne),
                 position = [x, y, z] (mm), velocity = [vx, vy, vz] (mm/s), optional penalty
                 (N/mm per node); a rigid body hitting the top face (``contact``)
Time curve (for prescribed/load): rise_time + profile ("smooth" or "linear"): 0 -> 1 over
rise_time, then held; or curve = [[t0, s0], [t1, s1], ...] (piecewise linear, held after).
"""

from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fenics_adaptive.cohesive import CohesiveLaw
from fenics_adaptive.contact import IMPACTOR_SHAPES, Impactor
from fenics_adaptive.enrichment import STRONG, WEAK
from fenics_adaptive.errors import InputError
from fenics_adaptive.explicit import Probe, SolverSettings
from fenics_adaptive.indicators import IndicatorSettings, Manual
from fenics_adaptive.laminate import Laminate, Ply, PlyMaterial
from fenics_adaptive.loading import COMPONENTS, Amplitude, FaceLoad, PrescribedMotion, clamp
from fenics_adaptive.ply_damage import PlyFailure
from fenics_adaptive.solid_shell import KINEMATICS
from fenics_adaptive.structure import Interfaces, Stabilisation

MODEL_KINDS = ("esl", "adaptive", "layerwise")
REFINEMENT_KINDS = ("weak", "strong")
BASE_FACES = ("x0", "x1", "y0", "y1", "bottom", "top")
SIDE_FACES = ("x0", "x1", "y0", "y1")


@dataclass(frozen=True)
class MeshConfig:
    length: float
    width: float
    nx: int
    ny: int
    layers: tuple[int, ...]  # plies per mesh layer, bottom to top


@dataclass(frozen=True)
class MatrixStrength:
    """Plies (0-based) whose matrix cracks at ``factor`` x YT in the cells with centroid x in
    [x_min, x_max] (see ``Structure.scale_matrix_strength``): < 1 seeds a flaw, > 1 keeps the
    cells under a roller (a line of nodes here, a contact patch in reality) from crushing."""

    plies: tuple[int, ...]
    factor: float
    x_min: float = -math.inf
    x_max: float = math.inf


@dataclass(frozen=True)
class RunConfig:
    kind: str
    points_per_ply: int
    mesh: MeshConfig
    laminate: Laminate
    motions: tuple[PrescribedMotion, ...]
    loads: tuple[FaceLoad, ...]
    solver: SolverSettings
    probe: Probe
    interfaces: Interfaces = field(default_factory=Interfaces)
    refinements: tuple[Manual, ...] = ()
    indicators: IndicatorSettings | None = None
    stabilisation: Stabilisation = field(default_factory=Stabilisation)
    failures: dict[str, PlyFailure] = field(default_factory=dict)
    ply_damage: bool = False
    kinematics: str = "small"  # solid_shell.KINEMATICS
    impactor: Impactor | None = None
    matrix_strength: tuple[MatrixStrength, ...] = ()
    cohesive: CohesiveLaw | None = None
    source: str = "<memory>"

    @property
    def layer_boundaries(self) -> list[int]:
        """Ply interfaces at the boundaries between mesh layers."""
        return list(itertools.accumulate(self.mesh.layers))[:-1]

    def layer_laminates(self) -> list[Laminate]:
        """The laminate of each mesh layer (one for ESL)."""
        plies = self.laminate.plies
        out, start = [], 0
        for count in self.mesh.layers:
            out.append(Laminate(plies[start : start + count]))
            start += count
        return out

    @property
    def face_names(self) -> list[str]:
        return face_names(len(self.mesh.layers))


def face_names(n_layers: int) -> list[str]:
    names = list(BASE_FACES)
    for k in range(n_layers):
        names += [f"{face}_layer{k}" for face in (*SIDE_FACES, "bottom", "top")]
    return names


class _Table:
    """A TOML table being read: typed getters that name the key in every error, and a final
    check that no key was left unread (unknown keys are errors)."""

    def __init__(self, path: str, data: Any):
        if not isinstance(data, dict):
            raise InputError(path, f"must be a table (got {type(data).__name__})")
        self.path = path
        self.data = data
        self.read: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, default: Any = ..., required: bool = True) -> Any:
        self.read.add(name)
        if name not in self.data:
            if default is not ...:
                return default
            if required:
                raise InputError(self.key(name), "missing")
            return None
        return self.data[name]

    def number(
        self,
        name: str,
        default: Any = ...,
        minimum: float | None = None,
        positive: bool = False,
        maximum: float | None = None,
    ) -> float:
        value = self.raw(name, default)
        if value is None and default is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(self.key(name), f"must be a number (got {value!r})")
        value = float(value)
        if not math.isfinite(value):
            raise InputError(self.key(name), f"must be finite (got {value})")
        if positive and not value > 0:
            raise InputError(self.key(name), f"must be > 0 (got {value:g})")
        if minimum is not None and value < minimum:
            raise InputError(self.key(name), f"must be >= {minimum:g} (got {value:g})")
        if maximum is not None and value > maximum:
            raise InputError(self.key(name), f"must be <= {maximum:g} (got {value:g})")
        return value

    def integer(self, name: str, default: Any = ..., minimum: int = 1) -> int | None:
        value = self.raw(name, default)
        if value is None and default is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(self.key(name), f"must be an integer >= {minimum} (got {value!r})")
        if value < minimum:
            raise InputError(self.key(name), f"must be an integer >= {minimum} (got {value})")
        return value

    def string(self, name: str, choices: tuple[str, ...] | list[str] | None = None, default=...):
        value = self.raw(name, default)
        if not isinstance(value, str):
            raise InputError(self.key(name), f"must be a string (got {value!r})")
        if choices is not None and value not in choices:
            raise InputError(self.key(name), f"must be one of {', '.join(choices)} (got {value!r})")
        return value

    def table(self, name: str, required: bool = True) -> _Table | None:
        value = self.raw(name, required=required)
        if value is None:
            return None
        return _Table(self.key(name), value)

    def array_of_tables(self, name: str) -> list[_Table]:
        value = self.raw(name, default=[])
        if not isinstance(value, list):
            raise InputError(self.key(name), "must be an array of tables ([[...]])")
        return [_Table(f"{self.key(name)}[{i}]", item) for i, item in enumerate(value)]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.read)
        if unknown:
            raise InputError(self.key(unknown[0]), "unknown key")


def load_config(path: str | Path) -> RunConfig:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise InputError(str(path), f"cannot read the config file ({error.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise InputError(str(path), f"not valid TOML ({error})") from None
    return parse_config(data, source=str(path))


def parse_config(data: dict, source: str = "<memory>") -> RunConfig:
    root = _Table("", data)

    model = root.table("model")
    kind = model.string("kind", MODEL_KINDS)
    points_per_ply = model.integer("points_per_ply", default=1)
    ply_damage = model.raw("ply_damage", default=False)
    if not isinstance(ply_damage, bool):
        raise InputError(model.key("ply_damage"), "must be true or false")
    if points_per_ply > 2:
        raise InputError(model.key("points_per_ply"), f"must be 1 or 2 (got {points_per_ply})")
    kinematics = model.string("kinematics", KINEMATICS, default="small")
    if kinematics == "finite" and ply_damage:
        # the ply damage kernel samples small strains; mixing it with finite kinematics would
        # silently damage rotating plies
        raise InputError(
            model.key("kinematics"),
            '"finite" cannot be combined with model.ply_damage = true (the ply damage model is '
            "small-strain only)",
        )
    model.finish()

    materials, failures = _materials(root.table("materials"))
    laminate = _laminate(root.table("laminate"), materials)
    mesh = _mesh(root.table("mesh"), kind, laminate)
    for k, count in enumerate(mesh.layers):
        if count * points_per_ply < 2:
            raise InputError(
                "mesh.layers" if kind == "layerwise" else "laminate",
                f"mesh layer {k} holds one ply with one integration point through the thickness:"
                " its bending mode has no stiffness (group plies, or set model.points_per_ply = 2)",
            )
    faces = face_names(len(mesh.layers))
    interfaces, refinements, cohesive = _interfaces(root, kind, laminate, mesh)
    stabilisation = _stabilisation(root, kind)
    impactor = _impactor(root)
    indicators = _indicators(root, kind, interfaces, cohesive, materials)
    used = sorted({p.material.name for p in laminate.plies})
    needs_failure = ply_damage or (indicators is not None and indicators.ply_failure is not None)
    for name in used if needs_failure else ():
        if name not in failures:
            why = "model.ply_damage" if ply_damage else "indicators.ply_failure"
            raise InputError(f"materials.{name}.failure", f"missing ({why} needs strengths)")
    if indicators is not None and indicators.matrix_damage and not ply_damage:
        raise InputError("indicators.matrix_damage", "needs model.ply_damage = true")
    flaws: list[MatrixStrength] = []
    for table in root.array_of_tables("matrix_strength"):
        if not ply_damage:
            raise InputError(table.key("plies"), "needs model.ply_damage = true")
        plies = table.raw("plies")
        if (
            not isinstance(plies, list)
            or not plies
            or any(
                isinstance(p, bool) or not isinstance(p, int) or not 1 <= p <= laminate.n_plies
                for p in plies
            )
        ):
            raise InputError(
                table.key("plies"), f"must list plies 1 .. {laminate.n_plies} (got {plies!r})"
            )
        factor = table.number("factor", positive=True, maximum=10.0)
        x_min = table.number("x_min") if table.has("x_min") else -math.inf
        x_max = table.number("x_max") if table.has("x_max") else math.inf
        table.finish()
        flaws.append(MatrixStrength(tuple(p - 1 for p in plies), factor, x_min, x_max))

    motions: list[PrescribedMotion] = []
    for table in root.array_of_tables("clamp"):
        face = _face(table, faces)
        x_range = _x_range(table, mesh)
        motions += [replace(m, x_range=x_range) for m in clamp(face)]
        table.finish()
    for table in root.array_of_tables("prescribed"):
        face = _face(table, faces)
        component = table.string("component", tuple(COMPONENTS))
        if table.has("displacement") == table.has("velocity"):
            raise InputError(
                table.key("displacement"), "give exactly one of displacement, velocity"
            )
        kind_of_motion = "displacement" if table.has("displacement") else "velocity"
        value = table.number(kind_of_motion)
        motions.append(
            PrescribedMotion(
                face, component, kind_of_motion, value, _amplitude(table), _x_range(table, mesh)
            )
        )
        table.finish()
    loads: list[FaceLoad] = []
    for table in root.array_of_tables("load"):
        face = _face(table, faces)
        force = table.raw("force")
        if (
            not isinstance(force, list)
            or len(force) != 3
            or any(isinstance(f, bool) or not isinstance(f, int | float) for f in force)
        ):
            raise InputError(table.key("force"), f"must be [Fx, Fy, Fz] in N (got {force!r})")
        loads.append(FaceLoad(face, tuple(float(f) for f in force), _amplitude(table)))
        table.finish()
    if not motions:
        raise InputError("clamp", "the model needs at least one [[clamp]] or [[prescribed]] face")

    solver_table = root.table("solver")
    end_time = solver_table.number("end_time", positive=True)
    safety = solver_table.number("safety_factor", default=0.9, positive=True, maximum=1.0)
    forced = solver_table.number("time_step", default=None, positive=True)
    damping = solver_table.number("mass_damping", default=0.0, minimum=0.0)
    solver_table.finish()

    output = root.table("output")
    interval = output.number("interval", positive=True)
    fields_interval = output.number("fields_interval", default=None, positive=True)
    checkpoint_interval = output.integer("checkpoint_interval", default=None)
    probe = Probe(
        displacement_face=_face(output, faces, "displacement_face"),
        reaction_face=_face(output, faces, "reaction_face"),
        component=output.string("component", tuple(COMPONENTS)),
        displacement_x=_x_range(output, mesh, "displacement_x"),
    )
    output.finish()
    if interval > end_time:
        raise InputError("output.interval", f"is longer than solver.end_time ({end_time:g} s)")
    constrained_faces = {m.face for m in motions}
    if probe.reaction_face not in constrained_faces:
        raise InputError(
            "output.reaction_face",
            f"{probe.reaction_face!r} is neither clamped nor prescribed; a reaction force exists "
            f"only there ({', '.join(sorted(constrained_faces))})",
        )
    root.finish()
    return RunConfig(
        kind=kind,
        points_per_ply=points_per_ply,
        mesh=mesh,
        laminate=laminate,
        motions=tuple(motions),
        loads=tuple(loads),
        solver=SolverSettings(
            end_time=end_time,
            output_interval=interval,
            safety_factor=safety,
            time_step=forced,
            mass_damping=damping,
            field_interval=fields_interval,
            checkpoint_interval=checkpoint_interval,
        ),
        probe=probe,
        interfaces=interfaces,
        refinements=refinements,
        indicators=indicators,
        stabilisation=stabilisation,
        failures=failures,
        ply_damage=ply_damage,
        kinematics=kinematics,
        impactor=impactor,
        matrix_strength=tuple(flaws),
        cohesive=cohesive,
        source=source,
    )


def _materials(table: _Table) -> tuple[dict[str, PlyMaterial], dict[str, PlyFailure]]:
    """Ply materials, and the failure data ([materials.NAME.failure]) of those that have it."""
    if not table.data:
        raise InputError("materials", "define at least one material ([materials.NAME])")
    materials, failures = {}, {}
    for name, values in table.data.items():
        table.read.add(name)
        if not isinstance(values, dict):
            raise InputError(f"materials.{name}", "must be a table of ply properties")
        elastic = {k: v for k, v in values.items() if k != "failure"}
        materials[name] = PlyMaterial.from_mapping(name, elastic)
        if "failure" in values:
            failures[name] = PlyFailure.from_mapping(name, values["failure"])
    return materials, failures


def _laminate(table: _Table, materials: dict[str, PlyMaterial]) -> Laminate:
    def material(key: str, name: Any) -> PlyMaterial:
        if name not in materials:
            raise InputError(key, f"unknown material {name!r} (defined: {', '.join(materials)})")
        return materials[name]

    if table.has("plies"):
        for name in ("material", "angles", "ply_thickness"):
            if table.has(name):
                raise InputError(table.key(name), "give either plies, or material + angles")
        plies_raw = table.array_of_tables("plies")
        if not plies_raw:
            raise InputError(table.key("plies"), "needs at least one ply")
        plies = []
        for ply_table in plies_raw:
            mat = material(ply_table.key("material"), ply_table.string("material"))
            angle = ply_table.number("angle", minimum=-360.0, maximum=360.0)
            thickness = ply_table.number("thickness", positive=True)
            ply_table.finish()
            plies.append(Ply(mat, angle, thickness))
    else:
        mat = material(table.key("material"), table.string("material"))
        thickness = table.number("ply_thickness", positive=True)
        angles = table.raw("angles")
        if not isinstance(angles, list) or not angles:
            raise InputError(table.key("angles"), "must be a non-empty list of ply angles (deg)")
        for i, angle in enumerate(angles):
            if isinstance(angle, bool) or not isinstance(angle, int | float):
                raise InputError(f"{table.key('angles')}[{i}]", f"must be a number (got {angle!r})")
            if not -360.0 <= angle <= 360.0:
                raise InputError(
                    f"{table.key('angles')}[{i}]", f"must be within [-360, 360] deg (got {angle})"
                )
        plies = [Ply(mat, float(a), thickness) for a in angles]
    table.finish()
    return Laminate(tuple(plies))


def _mesh(table: _Table, kind: str, laminate: Laminate) -> MeshConfig:
    length = table.number("length", positive=True)
    width = table.number("width", positive=True)
    nx = table.integer("nx")
    ny = table.integer("ny")
    if kind == "layerwise":
        layers = table.raw("layers", default=[1] * laminate.n_plies)
        if (
            not isinstance(layers, list)
            or not layers
            or any(isinstance(c, bool) or not isinstance(c, int) or c < 1 for c in layers)
        ):
            raise InputError(
                table.key("layers"), f"must be a list of ply counts >= 1 (got {layers!r})"
            )
        if sum(layers) != laminate.n_plies:
            raise InputError(
                table.key("layers"),
                f"groups {sum(layers)} plies but the laminate has {laminate.n_plies}",
            )
    else:
        if table.has("layers"):
            raise InputError(table.key("layers"), "only a layerwise model has mesh layers")
        layers = [laminate.n_plies]
    table.finish()
    return MeshConfig(length, width, nx, ny, tuple(layers))


def _face(table: _Table, faces: list[str], name: str = "face") -> str:
    """A face group, or several joined by & (their common nodes, e.g. x1&top: an edge)."""
    face = table.string(name)
    for part in face.split("&"):
        if part not in faces:
            raise InputError(
                table.key(name),
                f"unknown face {part!r} (known: {', '.join(faces)}; join faces with & for "
                "their common nodes)",
            )
    return face


def _x_range(table: _Table, mesh: MeshConfig, name: str = "x") -> tuple[float, float] | None:
    """Optional x selection of a face's nodes (mm): ``x`` for one line of nodes across the
    width (it must be a node line of the mesh), or ``x_min`` and ``x_max`` for a pad."""
    if table.has(name):
        x = table.number(name, minimum=0.0, maximum=mesh.length)
        cells = x / mesh.length * mesh.nx
        if abs(cells - round(cells)) > 1e-6:
            raise InputError(
                table.key(name),
                f"x = {x} mm is not on a node line (cells are {mesh.length / mesh.nx:g} mm long)",
            )
        return (x, x)
    if name != "x" or not (table.has("x_min") or table.has("x_max")):
        return None
    low = table.number("x_min", minimum=0.0, maximum=mesh.length)
    high = table.number("x_max", minimum=0.0, maximum=mesh.length)
    if high < low:
        raise InputError(table.key("x_max"), f"must be >= x_min ({low:g})")
    return (low, high)


def _interface_list(table: _Table, name: str, n_plies: int) -> tuple[int, ...]:
    values = table.raw(name, default=[])
    if not isinstance(values, list):
        raise InputError(table.key(name), "must be a list of ply interfaces (1-based)")
    for j, value in enumerate(values):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value < n_plies:
            raise InputError(
                f"{table.key(name)}[{j}]",
                f"must be a ply interface 1 .. {n_plies - 1} (got {value!r})",
            )
    if len(set(values)) != len(values):
        raise InputError(table.key(name), "lists an interface twice")
    return tuple(sorted(values))


def _interfaces(root: _Table, kind: str, laminate: Laminate, mesh: MeshConfig):
    n_plies = laminate.n_plies
    table = root.table("interfaces", required=False)
    refinement_tables = root.array_of_tables("refinement")
    cohesive_table = root.table("cohesive", required=False)
    if table is None:
        if kind == "adaptive":
            raise InputError("interfaces", "an adaptive model needs [interfaces] (refine = ...)")
        if refinement_tables:
            raise InputError("refinement", "only an adaptive model refines")
        if cohesive_table is not None:
            raise InputError("cohesive", "no interface delaminates ([interfaces] delaminate)")
        return Interfaces(), (), None
    if kind == "esl":
        raise InputError("interfaces", "an ESL model has no interfaces to refine (use adaptive)")
    refine = _interface_list(table, "refine", n_plies)
    delaminate = _interface_list(table, "delaminate", n_plies)
    symmetry = _interface_list(table, "symmetry", n_plies)
    initial = table.string("initial", ("none", "weak", "strong"), default="none")
    table.finish()
    if kind == "layerwise":
        boundaries = list(itertools.accumulate(mesh.layers))[:-1]
        if refine or initial != "none":
            key = "interfaces.refine" if refine else "interfaces.initial"
            raise InputError(key, "a layerwise model does not refine (its layers are fixed)")
        for name, values in (("delaminate", delaminate), ("symmetry", symmetry)):
            for value in values:
                if value not in boundaries:
                    raise InputError(
                        f"interfaces.{name}",
                        f"interface {value} is not a boundary between mesh layers "
                        f"(mesh.layers puts them at {boundaries})",
                    )
        if refinement_tables:
            raise InputError("refinement", "only an adaptive model refines")
    else:
        allowed = set(refine) | set(delaminate)
        for value in symmetry:
            if value not in allowed:
                raise InputError(
                    "interfaces.symmetry", f"interface {value} is not listed to refine"
                )
        if not allowed:
            raise InputError("interfaces.refine", "an adaptive model needs interfaces to refine")
    if set(symmetry) & set(delaminate):
        raise InputError("interfaces.symmetry", "a symmetry interface cannot also delaminate")

    refinements = []
    for rt in refinement_tables:
        if rt.has("time") == rt.has("displacement"):
            raise InputError(rt.key("time"), "give exactly one trigger: time (s) or displacement")
        time = rt.number("time", minimum=0.0) if rt.has("time") else math.inf
        displacement = (
            rt.number("displacement", positive=True) if rt.has("displacement") else math.inf
        )
        interfaces = _interface_list(rt, "interfaces", n_plies)
        if not interfaces:
            raise InputError(rt.key("interfaces"), "list the interfaces to refine")
        kind_name = rt.string("kind", REFINEMENT_KINDS)
        pool = delaminate if kind_name == "strong" else set(refine) | set(delaminate)
        for value in interfaces:
            if value not in pool:
                raise InputError(
                    rt.key("interfaces"),
                    f"interface {value} may not refine {kind_name}ly (see [interfaces])",
                )
        x_min = rt.number("x_min") if rt.has("x_min") else -math.inf
        x_max = rt.number("x_max") if rt.has("x_max") else math.inf
        if x_max <= x_min:
            raise InputError(rt.key("x_max"), "must be larger than x_min")
        rt.finish()
        kind_code = STRONG if kind_name == "strong" else WEAK
        refinements.append(Manual(interfaces, kind_code, time, displacement, x_min, x_max))

    cohesive = None
    if delaminate:
        if cohesive_table is None:
            raise InputError("cohesive", "interfaces delaminate but [cohesive] is missing")
        cohesive = CohesiveLaw.from_mapping(cohesive_table.data)
    elif cohesive_table is not None:
        raise InputError("cohesive", "no interface delaminates ([interfaces] delaminate)")
    return Interfaces(refine, delaminate, symmetry, initial), tuple(refinements), cohesive


def _vector3(table: _Table, name: str, unit: str) -> tuple[float, float, float]:
    value = table.raw(name)
    if (
        not isinstance(value, list)
        or len(value) != 3
        or any(isinstance(v, bool) or not isinstance(v, int | float) for v in value)
    ):
        raise InputError(table.key(name), f"must be [x, y, z] in {unit} (got {value!r})")
    return (float(value[0]), float(value[1]), float(value[2]))


def _impactor(root: _Table) -> Impactor | None:
    table = root.table("impactor", required=False)
    if table is None:
        return None
    impactor = Impactor(
        shape=table.string("shape", IMPACTOR_SHAPES),
        radius=table.number("radius", positive=True),
        mass=table.number("mass", positive=True),
        position=_vector3(table, "position", "mm"),
        velocity=_vector3(table, "velocity", "mm/s"),
        penalty=table.number("penalty", default=None, positive=True),
    )
    table.finish()
    return impactor


def _stabilisation(root: _Table, kind: str) -> Stabilisation:
    table = root.table("stabilisation", required=False)
    if table is None:
        return Stabilisation()
    if kind != "adaptive":
        raise InputError("stabilisation", "only an adaptive model refines, so only it stabilises")
    damping = table.number("damping", default=0.0, minimum=0.0)
    window = table.number("damping_window", default=0.0, minimum=0.0)
    release = table.number("release_window", default=0.0, minimum=0.0)
    table.finish()
    if (damping > 0.0) != (window > 0.0):
        raise InputError(
            "stabilisation.damping_window",
            "damping after weak refinement needs both damping (1/s) and damping_window (s)",
        )
    return Stabilisation(damping, window, release)


def _indicators(root: _Table, kind: str, interfaces: Interfaces, cohesive, materials):
    table = root.table("indicators", required=False)
    if table is None:
        return None
    if kind != "adaptive":
        raise InputError("indicators", "only an adaptive model refines")
    interval = table.number("interval", positive=True)
    ply_failure = table.number("ply_failure", positive=True) if table.has("ply_failure") else None
    interface_stress = (
        table.number("interface_stress", positive=True) if table.has("interface_stress") else None
    )
    matrix_damage = table.raw("matrix_damage", default=False)
    if not isinstance(matrix_damage, bool):
        raise InputError(table.key("matrix_damage"), "must be true or false")
    spread_rings = table.integer("spread", default=0, minimum=0)
    strong_after = table.number("strong_after", minimum=0.0) if table.has("strong_after") else None
    front = table.integer("front", default=0, minimum=0)
    table.finish()
    if front and not interfaces.delaminate:
        raise InputError(
            "indicators.front", "no interface may delaminate ([interfaces] delaminate)"
        )
    if strong_after is not None and not interfaces.delaminate:
        raise InputError(
            "indicators.strong_after", "no interface may delaminate ([interfaces] delaminate)"
        )
    if interface_stress is not None and not interfaces.delaminate:
        raise InputError(
            "indicators.interface_stress", "no interface may delaminate ([interfaces] delaminate)"
        )
    if matrix_damage and not interfaces.delaminate:
        raise InputError(
            "indicators.matrix_damage", "no interface may delaminate ([interfaces] delaminate)"
        )
    if ply_failure is None and interface_stress is None and not matrix_damage:
        raise InputError("indicators", "switch on at least one indicator")
    return IndicatorSettings(
        interval, ply_failure, interface_stress, matrix_damage, spread_rings, strong_after, front
    )


def _amplitude(table: _Table) -> Amplitude:
    if table.has("curve"):
        for name in ("rise_time", "profile"):
            if table.has(name):
                raise InputError(table.key(name), "give either curve, or rise_time + profile")
        curve = table.raw("curve")
        if (
            not isinstance(curve, list)
            or not curve
            or any(
                not isinstance(p, list)
                or len(p) != 2
                or any(isinstance(x, bool) or not isinstance(x, int | float) for x in p)
                for p in curve
            )
        ):
            raise InputError(table.key("curve"), "must be a list of [time (s), scale] pairs")
        times = tuple(float(p[0]) for p in curve)
        if times[0] < 0:
            raise InputError(table.key("curve"), "times must start at >= 0 s")
        try:
            return Amplitude(times, tuple(float(p[1]) for p in curve))
        except ValueError as error:
            raise InputError(table.key("curve"), str(error).removeprefix("amplitude: ")) from None
    rise_time = table.number("rise_time", positive=True)
    profile = table.string("profile", ("smooth", "linear"), default="smooth")
    return Amplitude.ramp(rise_time, smooth=profile == "smooth")
