"""Run configuration: a TOML file, checked completely before anything runs.

Units: N, mm, s, tonne (stress MPa, density tonne/mm^3, energy mJ). Every config file says so in
its header. Every problem is reported as one line naming the key, e.g.
``mesh.nx: must be an integer >= 1 (got 0)``; unknown keys are errors, never ignored.

Every section and key, with its type, unit, default and bounds, is declared once in
``fenics_adaptive.settings.schema`` (rendered as the config reference of the documentation); this
module reads each key through the checked accessor of its declared kind (``_Table``). Every
number must be finite. Besides each key's own bounds, the whole config is checked before
meshing: degenerate cells (``config_schema.MIN_LENGTH``, ``MAX_ASPECT``), the estimated memory of
the model (``[model] max_memory``, GB), faces and face combinations (a&b) that hold no node,
two motions that prescribe one DOF differently, unit slips of material data (``[model]
check_units``); the step count against ``[solver] max_steps`` once the time step is known
(``check_step_count``).

Sections (see demos/*.toml for complete examples and ``config_schema`` for every key):
  [model]        kind = "esl" | "adaptive" | "layerwise"; thickness_integration =
                 "preintegrated" (default) | "plies"; points_per_ply (1 or 2, default 2);
                 kinematics = "small" (default) | "finite" (total Lagrangian: large rotations;
                 damaged cells co-rotate); ply_damage; shear_correction (default true);
                 enhanced_strain (default true); check_units (default true);
                 max_memory (GB, default 16)
  [mesh]         length, width (mm), nx, ny (cells in-plane); layers = [plies per mesh layer]
                 for a layerwise model (default: one layer per ply); partition = "cost"
                 (default) | "cells" (how MPI ranks share the cells); rebalance (the
                 imbalance that re-cuts an adaptive run's partition, default 1.2; 0: never)
  [materials.NAME]  E1, E2, G12, nu12, nu23, rho, optional G23; [materials.NAME.failure]
  [laminate]     material + ply_thickness + angles (bottom to top), or plies = [{material,
                 angle, thickness}, ...]
  [[clamp]]      face                         all components held at zero
  [[prescribed]] face, component, displacement (mm) or velocity (mm/s), time curve
  [[load]]       face, force = [Fx, Fy, Fz] (N, total over the face), time curve
  [solver]       end_time, safety_factor, time_step (optional, forced), mass_damping (1/s),
                 mass_scaling ("none" | "selective"), mass_scaling_step (s, optional),
                 max_steps (default 1e9: more steps are refused), energy_error_limit (share of
                 the largest energy of the run the energy balance error may reach)
  [output]       interval (s between history rows), fields_interval (s, optional),
                 fields_plies, fields_box (mm), ply_fields_every (what the field files hold),
                 checkpoint_interval (steps, optional), displacement_face, reaction_face,
                 component
  [impactor]     shape ("sphere" | "cylinder", axis along y), radius (mm), mass (tonne),
                 position = [x, y, z] (mm), velocity = [vx, vy, vz] (mm/s), optional penalty
                 (N/mm per node), friction (Coulomb coefficient, default 0); a rigid body
                 hitting the top face (``contact``)
  [interfaces], [[refinement]], [cohesive], [[delamination]] (insert films), [[matrix_strength]],
                 [indicators], [stabilisation]
Time curve (for prescribed/load): rise_time + profile ("smooth" or "linear"): 0 -> 1 over
rise_time, then held; or curve = [[t0, s0], [t1, s1], ...] (piecewise linear, held after).
"""

from __future__ import annotations

import itertools
import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import Any

from fenics_adaptive.errors import InputError
from fenics_adaptive.materials.laminate import Laminate, Ply, PlyMaterial
from fenics_adaptive.settings.adaptivity import (
    DEFAULT_INTERFACE_STRESS,
    Delamination,
    IndicatorSettings,
    Interfaces,
    Manual,
    Stabilisation,
)
from fenics_adaptive.settings.kinds import (
    ImpactorShape,
    IndicatorKind,
    Kinematics,
    MeshKind,
    ModelKind,
    MotionKind,
    Partition,
    Profile,
    Refinement,
    RigidMotion,
    ThicknessIntegration,
)
from fenics_adaptive.settings.loads import (
    Amplitude,
    FaceLoad,
    Impactor,
    Lever,
    PrescribedMotion,
    Region,
    RigidBody,
    clamp,
)
from fenics_adaptive.settings.materials import CohesiveLaw, PlyFailure
from fenics_adaptive.settings.schema import (
    MAX_ASPECT,
    MAX_PLIES,
    MAX_TIME,
    MIN_LENGTH,
    REBALANCE,
    REQUIRED,
    TOP_LEVEL,
    Key,
    Section,
    implausible,
    section,
)
from fenics_adaptive.settings.shells import KIND_KEYS, ShellShape, refuse_other_keys, shell_shape
from fenics_adaptive.settings.solver import FieldSelection, Probe, SolverSettings

SIDE_FACES = ("x0", "x1", "y0", "y1")


@dataclass(frozen=True)
class MeshConfig:
    length: float  # a plate's; 0 for a shell (its sizes are in ``shell``)
    width: float
    nx: int
    ny: int
    layers: tuple[int, ...]  # plies per mesh layer, bottom to top
    partition: Partition = Partition.COST  # on several ranks: patches of equal cost or cells
    shell: ShellShape | None = None  # a curved (or unstructured) shell's [mesh]; None: a plate
    # on several ranks: the imbalance that re-cuts an adaptive run's partition (0: never)
    rebalance: float = REBALANCE

    @property
    def kind(self) -> MeshKind:
        return MeshKind.PLATE if self.shell is None else self.shell.kind

    @property
    def structured(self) -> bool:
        """The flat plate of nx x ny cells, whose node sets the config can check exactly (a
        shell's faces are checked when its mesh is built: ``model.loading.resolve``)."""
        return self.shell is None


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
    kind: ModelKind
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
    # elements whose plies' fibres have all failed leave the force computation, and those
    # crushed below this volume ratio
    erosion: bool = False
    erosion_volume_ratio: float = 0.2
    kinematics: Kinematics = Kinematics.SMALL
    # transverse shear correction of the elements (materials.laminate.shear_correction_factors)
    shear_correction: bool = True
    # the enhanced assumed thickness strain (element.solid_shell)
    enhanced_strain: bool = True
    # through-thickness rule (element.solid_shell.thickness_rule)
    thickness_integration: ThicknessIntegration = ThicknessIntegration.PREINTEGRATED
    impactor: Impactor | None = None
    rigid_bodies: tuple[RigidBody, ...] = ()
    lever: Lever | None = None
    matrix_strength: tuple[MatrixStrength, ...] = ()
    cohesive: CohesiveLaw | None = None
    delaminations: tuple[Delamination, ...] = ()
    fields: FieldSelection = field(default_factory=FieldSelection)
    source: str = "<memory>"

    @property
    def preintegrate(self) -> bool:
        """The elements take the pre-integrated through-thickness rule where it applies: asked
        for, and no ply damage (whose kernel integrates ply by ply)."""
        return self.thickness_integration == ThicknessIntegration.PREINTEGRATED and not (
            self.ply_damage
        )

    @property
    def loading_bodies(self) -> list[str]:
        """The names of the history's ``<name>_force`` and ``<name>_displacement`` columns: the
        [[rigid]] bodies, then the lever's load point and hinge."""
        names = [body.name for body in self.rigid_bodies]
        return [*names, "lever", "hinge"] if self.lever is not None else names

    @property
    def body_columns(self) -> list[str]:
        """The history's rigid-body columns in order: ``<name>_force`` and
        ``<name>_displacement`` of each ``loading_bodies`` name, then
        ``<name>_friction_energy`` of each body with friction (the [impactor]'s too)."""
        columns = [
            f"{name}_{what}" for name in self.loading_bodies for what in ("force", "displacement")
        ]
        bodies = [
            *([self.impactor.body()] if self.impactor is not None else []),
            *self.rigid_bodies,
        ]
        return columns + [f"{b.name}_friction_energy" for b in bodies if b.friction > 0.0]

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
        return face_names(len(self.mesh.layers), self.mesh.shell)


def face_names(n_layers: int, shell: ShellShape | None = None) -> list[str]:
    """The face groups of a mesh of ``n_layers`` layers: a plate's sides x0, x1, y0, y1, or a
    shell's edges, then bottom and top, and each of them per layer."""
    sides = SIDE_FACES if shell is None else shell.edges
    names = [*sides, "bottom", "top"]
    for k in range(n_layers):
        names += [f"{face}_layer{k}" for face in (*sides, "bottom", "top")]
    return names


class _Reading:
    """What every table of one config shares while it is read: whether unit plausibility is
    checked, and (for the schema coverage test) the schema keys read, as "section.key"."""

    def __init__(self, seen: set[str] | None):
        self.check_units = True
        self.seen = seen


def _type_name(value: Any) -> str:
    return {dict: "a table", list: "a list", str: "a string", bool: "a boolean"}.get(
        type(value), type(value).__name__
    )


def _name(name: str) -> str:
    """A key as an error message names it: as written if it is a plain name, else quoted (a
    TOML key may hold any character, a newline too, and the message stays one line)."""
    return name if re.fullmatch(r"[A-Za-z0-9_\-]+", name) else repr(name)


def _shown(value: Any) -> str:
    """A value for an error message: its repr, cut short (one line, whatever the value)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _expect(
    value: Any,
    kind: type | tuple[type, ...],
    key: str,
    what: str,
    ok: Callable[[Any], Any] | None = None,
    shown: Callable[[Any], str] = _shown,
) -> Any:
    """The one type check of a config value: ``value`` if it is a ``kind`` (a TOML boolean is
    a ``bool`` only, never a number) and ``ok(value)`` holds (if given); else raises
    ``KEY: must be WHAT (got VALUE)``."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    right_type = isinstance(value, kinds) and (bool in kinds or not isinstance(value, bool))
    if not right_type or (ok is not None and not ok(value)):
        raise InputError(key, f"must be {what} (got {shown(value)})")
    return value


def _is_pair(value: list) -> bool:
    """Whether a list is a pair (a point [time, scale] of a time curve)."""
    return len(value) == 2


def _bound_problem(spec: Key, value: float, low: float | None, high: float | None) -> str | None:
    """The problem of a number outside its bounds (the schema's, narrowed by ``low``/``high``)."""
    unit = f" {spec.unit}" if spec.unit else ""
    lowest, open_low = spec.minimum, spec.open_min
    if low is not None and (lowest is None or low > lowest):
        lowest, open_low = low, False
    highest, open_high = spec.maximum, spec.open_max
    if high is not None and (highest is None or high < highest):
        highest, open_high = high, False
    if lowest is not None and (value < lowest or (open_low and value == lowest)):
        return f"must be {'>' if open_low else '>='} {lowest:g}{unit} (got {value:g})"
    if highest is not None and (value > highest or (open_high and value == highest)):
        return f"must be {'<' if open_high else '<='} {highest:g}{unit} (got {value:g})"
    return None


class _Table:
    """A TOML table being read against its schema section (``config_schema``): one checked
    accessor per kind of value, each naming the key in its error; keys the schema does not
    declare are refused at once, and a key is read only through the accessor of its declared
    kind, so a new key cannot skip its checks."""

    def __init__(self, path: str, data: Any, schema: Section, reading: _Reading):
        _expect(data, dict, path, "a table", shown=_type_name)
        for name in data:
            if name in schema.retired:
                retired = schema.retired[name]
                raise InputError(f"{path}.{_name(name)}", f"no longer a key: {retired}")
            if name not in schema.by_name:
                raise InputError(
                    f"{path}.{_name(name)}", f"unknown key (allowed: {', '.join(schema.names)})"
                )
        self.path = path
        self.data = data
        self.schema = schema
        self.reading = reading

    def key(self, name: str) -> str:
        return f"{self.path}.{name}"

    def has(self, name: str) -> bool:
        self.schema.key(name)  # a name the schema does not declare is a programming error
        return name in self.data

    def _value(self, name: str, kind: str) -> Any:
        """The given value, the schema default, or None (optional, absent); raises if a required
        key is missing."""
        spec = self.schema.key(name)
        if spec.kind != kind:
            raise TypeError(f"config schema: {self.key(name)} is a {spec.kind}, read as {kind}")
        if self.reading.seen is not None:
            self.reading.seen.add(f"{self.schema.name}.{name}")
        if name in self.data:
            return self.data[name]
        if spec.default is REQUIRED:
            raise InputError(self.key(name), "missing")
        return spec.default

    def _check_number(self, name: str, value: Any, key: str, low=None, high=None) -> float:
        spec = self.schema.key(name)
        unit = f" in {spec.unit}" if spec.unit else ""
        _expect(value, (int, float), key, f"a number{unit}")
        value = float(value)
        if not math.isfinite(value):
            raise InputError(key, f"must be a finite number{unit} (got {value})")
        problem = _bound_problem(spec, value, low, high)
        if problem is None and self.reading.check_units:
            problem = implausible(spec, value)
        if problem is not None:
            raise InputError(key, problem)
        return value

    def number(self, name: str, low: float | None = None, high: float | None = None):
        """A finite number within the schema's bounds (and ``low`` .. ``high``), or the
        default (None for an optional key left out)."""
        value = self._value(name, "float")
        if value is None or name not in self.data:
            return value
        return self._check_number(name, value, self.key(name), low, high)

    def _check_integer(self, name: str, value: Any, key: str, high: int | None = None) -> int:
        spec = self.schema.key(name)
        # 1e5 is a float in TOML; an integral float is the integer it names
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            value = int(value)
        _expect(value, int, key, "an integer")
        problem = _bound_problem(spec, value, None, high)
        if problem is not None:
            raise InputError(key, problem.replace("must be", "must be an integer", 1))
        return value

    def integer(self, name: str, high: int | None = None) -> int | None:
        value = self._value(name, "int")
        if value is None or name not in self.data:
            return value
        return self._check_integer(name, value, self.key(name), high)

    def boolean(self, name: str) -> bool | None:
        """true or false, or the default (None for an optional key left out)."""
        value = self._value(name, "bool")
        if value is None and name not in self.data:
            return None
        return _expect(value, bool, self.key(name), "true or false")

    def choice(self, name: str) -> str:
        """One of the schema's choices: the enum member if the choices are an enum's
        (``settings.kinds``), else the string."""
        value = self._value(name, "choice")
        choices = self.schema.key(name).choices
        what = f"one of {', '.join(choices)}"
        _expect(value, str, self.key(name), what, ok=lambda v: v in choices)
        kind = type(choices[0])
        return kind(value) if issubclass(kind, Enum) else value

    def string(self, name: str) -> str | None:
        value = self._value(name, "string")
        if value is None:
            return None
        return _expect(value, str, self.key(name), "a non-empty string", ok=bool)

    def face(self, name: str, faces: list[str], single: bool = False) -> str:
        """A face group, or with & the common nodes of several (``single``: one face only)."""
        value = self._value(name, "face")
        _expect(value, str, self.key(name), "a face name")
        parts = value.split("&")
        if single and len(parts) > 1:
            raise InputError(self.key(name), f"{value!r}: a load acts on one face, not on a&b")
        for part in parts:
            if part not in faces:
                raise InputError(
                    self.key(name),
                    f"unknown face {part!r} (known: {', '.join(faces)}; join faces with & for "
                    "their common nodes)",
                )
        return value

    def numbers(self, name: str) -> tuple[float, ...] | None:
        """A list of finite numbers (the schema's length, if it has one), each within the
        schema's bounds."""
        value = self._value(name, "floats")
        if name not in self.data:
            return value
        spec = self.schema.key(name)
        what = (
            f"[{', '.join('xyz')}]"
            if spec.length == 3
            else f"a list of {spec.length} numbers"
            if spec.length
            else "a non-empty list of numbers"
        )
        unit = f" in {spec.unit}" if spec.unit else ""
        _expect(
            value,
            list,
            self.key(name),
            f"{what}{unit}",
            ok=lambda v: v and not (spec.length and len(v) != spec.length),
        )
        return tuple(
            self._check_number(name, v, f"{self.key(name)}[{i}]") for i, v in enumerate(value)
        )

    def integers(self, name: str, high: int | None = None, unique: bool = True) -> tuple[int, ...]:
        """A list of integers within the schema's bounds (and <= ``high``), no repeats."""
        value = self._value(name, "ints")
        if name not in self.data:
            return value
        _expect(value, list, self.key(name), "a list of integers")
        out = tuple(
            self._check_integer(name, v, f"{self.key(name)}[{i}]", high)
            for i, v in enumerate(value)
        )
        if unique and len(set(out)) != len(out):
            raise InputError(self.key(name), f"lists a value twice (got {list(out)})")
        return out

    def curve(self, name: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """A time curve [[t0, s0], [t1, s1], ...]: times (s) from 0, not decreasing."""
        value = self._value(name, "curve")
        if name not in self.data:
            return value
        key = self.key(name)
        _expect(value, list, key, "a list of [time (s), scale] pairs", ok=bool)
        times, scales = [], []
        for i, pair in enumerate(value):
            pair_key = f"{key}[{i}]"
            _expect(pair, list, pair_key, "a [time (s), scale] pair", ok=_is_pair, shown=repr)
            times.append(self._check_number(name, pair[0], f"{key}[{i}][0]", 0.0, MAX_TIME))
            scales.append(self._check_number(name, pair[1], f"{key}[{i}][1]"))
            if i and times[-1] < times[-2]:
                raise InputError(
                    f"{key}[{i}][0]", f"times must not decrease ({times[-2]:g} s before)"
                )
        return tuple(times), tuple(scales)

    def pairs(self, name: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        """A list [[x0, v0], [x1, v1], ...] of finite numbers, x strictly increasing."""
        value = self._value(name, "pairs")
        if name not in self.data:
            return value
        key = self.key(name)
        _expect(value, list, key, "a list of [x, value] pairs", ok=bool)
        xs, values = [], []
        for i, pair in enumerate(value):
            pair_key = f"{key}[{i}]"
            _expect(pair, list, pair_key, "an [x, value] pair", ok=_is_pair, shown=repr)
            xs.append(self._check_number(name, pair[0], f"{key}[{i}][0]"))
            values.append(self._check_number(name, pair[1], f"{key}[{i}][1]"))
            if i and xs[-1] <= xs[-2]:
                raise InputError(f"{key}[{i}][0]", f"x must increase ({xs[-2]:g} before)")
        return tuple(xs), tuple(values)

    def table(self, name: str) -> _Table | None:
        """A sub-table, read against the schema section ``<this section>.<name>``."""
        value = self._value(name, "table")
        if value is None:
            return None
        return _Table(self.key(name), value, section(f"{self.schema.name}.{name}"), self.reading)

    def tables(self, name: str) -> list[_Table]:
        """An array of tables, each read against the section ``<this section>.<name>``."""
        value = self._value(name, "tables")
        if value is None:
            return []
        _expect(value, list, self.key(name), "an array of tables")
        schema = section(f"{self.schema.name}.{name}")
        return [
            _Table(f"{self.key(name)}[{i}]", t, schema, self.reading) for i, t in enumerate(value)
        ]

    def range(self, low: str, high: str, strict: bool = False) -> tuple[float, float]:
        """A pair of number keys (x_min, x_max): each optional (-inf, +inf), and the upper one
        refused below (``strict``: at or below) the lower one."""
        lo, hi = self.number(low), self.number(high)
        lo = -math.inf if lo is None else lo
        hi = math.inf if hi is None else hi
        if hi < lo or (strict and hi == lo):
            raise InputError(
                self.key(high), f"must be {'>' if strict else '>='} {low} = {lo:g} (got {hi:g})"
            )
        return lo, hi


class _Root:
    """The top level of a config: the sections of the schema, and nothing else."""

    def __init__(self, data: Any, reading: _Reading):
        _expect(data, dict, "config", "a table", shown=_type_name)
        for name in data:
            if name not in TOP_LEVEL:
                raise InputError(_name(name), f"unknown section (allowed: {', '.join(TOP_LEVEL)})")
        self.data = data
        self.reading = reading

    def table(self, name: str) -> _Table | None:
        schema = section(name)
        if name not in self.data:
            if schema.required:
                raise InputError(name, f"missing (a [{name}] section is needed)")
            return None
        return _Table(name, self.data[name], schema, self.reading)

    def tables(self, name: str) -> list[_Table]:
        schema = section(name)
        value = self.data.get(name, [])
        if not isinstance(value, list):
            raise InputError(name, f"must be an array of tables ([[{name}]])")
        return [_Table(f"{name}[{i}]", t, schema, self.reading) for i, t in enumerate(value)]


def load_config(path: str | Path) -> RunConfig:
    """Read and check a TOML config file; every problem is an ``InputError`` (one line)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise InputError(str(path), f"cannot read the config file ({error.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise InputError(
            str(path),
            f"not UTF-8 text (byte 0x{raw[error.start]:02x} at line {line}); save it as UTF-8",
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        problem = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise InputError(str(path), f"not valid TOML ({problem})") from None
    return parse_config(data, source=str(path))


def parse_config(data: dict, source: str = "<memory>", seen: set[str] | None = None) -> RunConfig:
    """Check a config (the dict of a TOML file) completely and build the run's objects.

    The tables are read in a fixed order (each reader may depend on those before it), so the
    first problem reported is always the same one.

    Parameters:
        data: the parsed TOML.
        source: where it came from (kept in the summary).
        seen: if given, filled with every schema key read, as "section.key".
    Raises:
        InputError: the first problem, one line naming the key.
    """
    root = _Root(data, _Reading(seen))
    model = _model(root.table("model"))
    materials, failures = _materials(root)
    laminate = _laminate(root.table("laminate"), materials)
    mesh = _mesh(root.table("mesh"), model.kind, laminate, source)
    _check_model_size(model, mesh, laminate)
    if mesh.structured:
        _check_geometry(mesh, laminate)
    faces = face_names(len(mesh.layers), mesh.shell)
    interfaces, refinements, cohesive = _interfaces(root, model.kind, laminate, mesh)
    split = _split_boundaries(model.kind, mesh, interfaces)
    stabilisation = _stabilisation(root, model.kind)
    impactor = _impactor(root)
    rigid_bodies = _rigid_bodies(root)
    lever = _lever(root, rigid_bodies, faces)
    indicators = _indicators(root, model.kind, interfaces)
    _check_failure_data(laminate, failures, model.ply_damage, indicators)
    _check_erosion(laminate, failures, model)
    flaws = _matrix_strength(root, model.ply_damage, laminate, mesh)
    delaminations = _delaminations(root, model.kind, interfaces, mesh)
    motions, loads = _motions_and_loads(root, model.kind, faces, mesh, split, interfaces)
    solver, probe, fields = _solver_and_output(root, faces, mesh, split, motions, laminate.n_plies)
    return RunConfig(
        kind=model.kind,
        points_per_ply=model.points_per_ply,
        shear_correction=model.shear_correction,
        enhanced_strain=model.enhanced_strain,
        thickness_integration=model.thickness_integration,
        mesh=mesh,
        laminate=laminate,
        motions=tuple(motions),
        loads=tuple(loads),
        solver=solver,
        probe=probe,
        interfaces=interfaces,
        refinements=refinements,
        indicators=indicators,
        stabilisation=stabilisation,
        failures=failures,
        ply_damage=model.ply_damage,
        erosion=model.erosion,
        erosion_volume_ratio=model.erosion_volume_ratio,
        kinematics=model.kinematics,
        impactor=impactor,
        rigid_bodies=rigid_bodies,
        lever=lever,
        matrix_strength=flaws,
        cohesive=cohesive,
        delaminations=delaminations,
        fields=fields,
        source=source,
    )


@dataclass(frozen=True)
class _Model:
    """The [model] table: the kind of model and the options the other tables depend on."""

    kind: ModelKind
    points_per_ply: int
    ply_damage: bool
    erosion: bool
    erosion_volume_ratio: float
    kinematics: Kinematics
    max_memory: float  # GB
    shear_correction: bool
    enhanced_strain: bool
    thickness_integration: ThicknessIntegration


def _model(table: _Table) -> _Model:
    """[model]. Its ``check_units`` is read first: every number read after it obeys it."""
    table.reading.check_units = table.boolean("check_units")
    model = _Model(
        kind=table.choice("kind"),
        points_per_ply=table.integer("points_per_ply"),
        ply_damage=table.boolean("ply_damage"),
        erosion=table.boolean("erosion"),
        erosion_volume_ratio=table.number("erosion_volume_ratio"),
        kinematics=table.choice("kinematics"),
        max_memory=table.number("max_memory"),
        shear_correction=table.boolean("shear_correction"),
        enhanced_strain=table.boolean("enhanced_strain"),
        thickness_integration=table.choice("thickness_integration"),
    )
    if table.has("erosion_volume_ratio") and not model.erosion:
        raise InputError(table.key("erosion_volume_ratio"), "needs model.erosion = true")
    return model


def _check_model_size(model: _Model, mesh: MeshConfig, laminate: Laminate) -> None:
    """Every mesh layer has bending stiffness through its thickness, and the estimated memory
    of the model stays within ``model.max_memory`` (GB)."""
    for k, count in enumerate(mesh.layers):
        if count * model.points_per_ply < 2:
            raise InputError(
                "mesh.layers" if model.kind == ModelKind.LAYERWISE else "laminate",
                f"mesh layer {k} holds one ply with one integration point through the thickness:"
                " its bending mode has no stiffness (group plies, or set model.points_per_ply = 2)",
            )
    size = model_size(mesh, laminate)
    memory = estimated_memory(size)
    if memory > model.max_memory * 1e9:
        raise InputError(
            ("mesh.nx" if mesh.nx >= mesh.ny else "mesh.ny") if mesh.structured else "mesh.kind",
            f"the model would have {size.cells:.4g} cells of {laminate.n_plies} plies in "
            f"{size.cell_layers} cell layer(s), an estimated {memory / 1e9:.3g} GB, above "
            f"model.max_memory = {model.max_memory:g} GB (raise it to run this model)",
        )


def _check_erosion(laminate: Laminate, failures: dict[str, PlyFailure], model: _Model) -> None:
    """Erosion removes elements whose fibres have broken: it needs ply damage and fibre
    fracture energies for the materials of the laminate (else nothing could ever erode)."""
    if not model.erosion:
        return
    if not model.ply_damage:
        raise InputError("model.erosion", "needs model.ply_damage = true")
    names = sorted({ply.material.name for ply in laminate.plies})
    without = [name for name in names if not failures[name].fibre_damage]
    if without:
        raise InputError(
            f"materials.{without[0]}.failure.Gft",
            "missing: model.erosion removes elements whose fibres have all broken, and the "
            "fibres break only with the fibre fracture energies Gft and Gfc",
        )


def _check_failure_data(
    laminate: Laminate,
    failures: dict[str, PlyFailure],
    ply_damage: bool,
    indicators: IndicatorSettings | None,
) -> None:
    """Ply damage and the ply failure indicator need the strengths of every material used;
    the matrix damage indicator needs ply damage."""
    used = sorted({p.material.name for p in laminate.plies})
    needs_failure = ply_damage or (indicators is not None and indicators.ply_failure is not None)
    for name in used if needs_failure else ():
        if name not in failures:
            why = "model.ply_damage" if ply_damage else "indicators.ply_failure"
            raise InputError(f"materials.{name}.failure", f"missing ({why} needs strengths)")
    if indicators is not None and indicators.matrix_damage and not ply_damage:
        raise InputError("indicators.matrix_damage", "needs model.ply_damage = true")


def _matrix_strength(
    root: _Root, ply_damage: bool, laminate: Laminate, mesh: MeshConfig
) -> tuple[MatrixStrength, ...]:
    """[[matrix_strength]]: plies (1-based in the file, 0-based here) whose matrix strength is
    scaled in an x range of cell centroids (mm); only with ply damage."""
    flaws: list[MatrixStrength] = []
    for table in root.tables("matrix_strength"):
        if not ply_damage:
            raise InputError(table.key("plies"), "needs model.ply_damage = true")
        plies = table.integers("plies", high=laminate.n_plies)
        if not plies:
            raise InputError(table.key("plies"), f"list plies 1 .. {laminate.n_plies}")
        factor = table.number("factor")
        x_min, x_max = table.range("x_min", "x_max")
        _check_holds_centroids(table, mesh, x_min, x_max)
        flaws.append(MatrixStrength(tuple(p - 1 for p in plies), factor, x_min, x_max))
    return tuple(flaws)


def _delaminations(
    root: _Root, kind: ModelKind, interfaces: Interfaces, mesh: MeshConfig
) -> tuple[Delamination, ...]:
    """[[delamination]]: insert films, each on an interface that may delaminate, over a region
    (mm) that holds at least one cell centroid."""
    inserts: list[Delamination] = []
    for table in root.tables("delamination"):
        if kind == ModelKind.ESL:
            raise InputError(
                table.key("interface"), "an ESL model has no interfaces (use layerwise or adaptive)"
            )
        interface = table.integer("interface")
        if interface not in interfaces.delaminate:
            allowed = list(interfaces.delaminate) or "none"
            raise InputError(
                table.key("interface"),
                f"interface {interface} does not delaminate ([interfaces] delaminate: {allowed})",
            )
        x_min, x_max = table.range("x_min", "x_max", strict=True)
        y_min, y_max = table.range("y_min", "y_max", strict=True)
        _check_holds_centroids(table, mesh, x_min, x_max)
        _check_holds_centroids(table, mesh, y_min, y_max, axis="y")
        inserts.append(Delamination(interface, Region(x_min, x_max, y_min, y_max)))
    return tuple(inserts)


def _motions_and_loads(
    root: _Root,
    kind: ModelKind,
    faces: list[str],
    mesh: MeshConfig,
    split: tuple[bool, ...],
    interfaces: Interfaces,
) -> tuple[list[PrescribedMotion], list[FaceLoad]]:
    """The boundary conditions: [[clamp]] and [[prescribed]] faces (which must not prescribe
    one DOF twice, the symmetry interfaces' u_z = 0 included), then the [[load]] faces."""
    motions = _motions(root, faces, mesh, split)
    symmetry = _symmetry_motions(kind, mesh, interfaces)
    if mesh.structured:  # a shell's: when its mesh is built (``model.loading.resolve``)
        _check_motions_agree([*motions, *symmetry], mesh, split)
    loads = _loads(root, faces)
    if not motions:
        raise InputError("clamp", "the model needs at least one [[clamp]] or [[prescribed]] face")
    return motions, loads


def _motions(
    root: _Root, faces: list[str], mesh: MeshConfig, split: tuple[bool, ...]
) -> list[PrescribedMotion]:
    """[[clamp]] (every component held at zero) then [[prescribed]] faces, each holding nodes."""
    motions: list[PrescribedMotion] = []
    for table in root.tables("clamp"):
        face = table.face("face", faces)
        x_range = _x_range(table, mesh)
        _check_has_nodes(table.key("face"), face, x_range, mesh, split)
        motions += [replace(m, x_range=x_range, key=table.key("face")) for m in clamp(face)]
    for table in root.tables("prescribed"):
        motions.append(_prescribed(table, faces, mesh, split))
    return motions


def _prescribed(
    table: _Table, faces: list[str], mesh: MeshConfig, split: tuple[bool, ...]
) -> PrescribedMotion:
    """One [[prescribed]] face: a displacement (mm) or a velocity (mm/s) of one component."""
    face = table.face("face", faces)
    component = table.choice("component")
    if table.has("displacement") == table.has("velocity"):
        raise InputError(table.key("displacement"), "give exactly one of displacement, velocity")
    kind = MotionKind.DISPLACEMENT if table.has("displacement") else MotionKind.VELOCITY
    value = table.number(kind)
    x_range = _x_range(table, mesh)
    _check_has_nodes(table.key("face"), face, x_range, mesh, split)
    return PrescribedMotion(
        face, component, kind, value, _amplitude(table), x_range, key=table.key("face")
    )


def _loads(root: _Root, faces: list[str]) -> list[FaceLoad]:
    """[[load]]: a total force (N) or a pressure (MPa, optionally distributed along x) on one
    face each, or on the part of it in an x, y region (mm), with its time curve."""
    loads: list[FaceLoad] = []
    for table in root.tables("load"):
        face = table.face("face", faces, single=True)
        if table.has("force") == table.has("pressure"):
            raise InputError(
                table.key("force"), "give exactly one of force (N, total) or pressure (MPa)"
            )
        force = table.numbers("force")
        pressure = table.number("pressure")
        distribution = table.pairs("distribution")
        if distribution is not None and pressure is None:
            raise InputError(table.key("distribution"), "shapes a pressure: give pressure")
        x_min, x_max = table.range("x_min", "x_max")
        y_min, y_max = table.range("y_min", "y_max")
        loads.append(
            FaceLoad(
                face,
                force,
                _amplitude(table),
                key=table.key("face"),
                pressure=pressure,
                distribution=distribution,
                region=Region(x_min, x_max, y_min, y_max),
            )
        )
    return loads


def _solver_and_output(
    root: _Root,
    faces: list[str],
    mesh: MeshConfig,
    split: tuple[bool, ...],
    motions: list[PrescribedMotion],
    n_plies: int,
) -> tuple[SolverSettings, Probe, FieldSelection]:
    """[solver] then [output]: the time integration and output settings, the probe and what
    the field files hold."""
    solver_options = _solver_options(root.table("solver"))
    table = root.table("output")
    output_options, probe = _output(table, solver_options["end_time"], faces, mesh, split, motions)
    fields = _field_selection(table, n_plies)
    if output_options["field_interval"] is None:
        for key in ("fields_plies", "fields_box", "ply_fields_every"):
            if table.has(key):  # (else silently without effect)
                raise InputError(table.key(key), "selects field output: set fields_interval too")
    if "mass_scaling_step" in solver_options and solver_options.get("mass_scaling") != "selective":
        raise InputError(
            "solver.mass_scaling_step", 'is the target step of mass_scaling = "selective"'
        )
    return SolverSettings(**solver_options, **output_options), probe, fields


def _field_selection(table: _Table, n_plies: int) -> FieldSelection:
    """[output] fields_plies, fields_box, ply_fields_every."""
    plies = table.integers("fields_plies", high=n_plies)
    box = table.numbers("fields_box")
    if box is not None:
        for axis, (low, high) in zip("xyz", zip(box[0::2], box[1::2], strict=True), strict=True):
            if low > high:
                raise InputError(
                    table.key("fields_box"),
                    f"{axis}_min {low:g} mm is above {axis}_max {high:g} mm; the box is "
                    "[x_min, x_max, y_min, y_max, z_min, z_max]",
                )
    return FieldSelection(
        plies=tuple(sorted(plies)) if plies else None,
        box=box,
        ply_every=table.integer("ply_fields_every"),
    )


def _solver_options(table: _Table) -> dict[str, Any]:
    """[solver], as ``SolverSettings`` keywords; keys left out keep ``SolverSettings``' own
    defaults (which the schema states)."""
    options = {
        "end_time": table.number("end_time"),
        "safety_factor": table.number("safety_factor"),
        "time_step": table.number("time_step"),
        "mass_damping": table.number("mass_damping"),
    }
    if table.has("mass_scaling"):
        options["mass_scaling"] = table.choice("mass_scaling")
    if table.has("mass_scaling_step"):
        options["mass_scaling_step"] = table.number("mass_scaling_step")
    if table.has("max_steps"):
        options["max_steps"] = table.integer("max_steps")
    if table.has("energy_error_limit"):
        options["energy_error_limit"] = table.number("energy_error_limit")
    return options


def _output(
    table: _Table,
    end_time: float,
    faces: list[str],
    mesh: MeshConfig,
    split: tuple[bool, ...],
    motions: list[PrescribedMotion],
) -> tuple[dict[str, Any], Probe]:
    """[output]: its intervals as ``SolverSettings`` keywords, and the probe of the history
    (a displacement on a face holding nodes, the reaction on a clamped or prescribed face)."""
    options = {
        "output_interval": table.number("interval"),
        "field_interval": table.number("fields_interval"),
        "checkpoint_interval": table.integer("checkpoint_interval"),
    }
    probe = Probe(
        displacement_face=table.face("displacement_face", faces),
        reaction_face=table.face("reaction_face", faces),
        component=table.choice("component"),
        displacement_x=_x_range(table, mesh, "displacement_x"),
    )
    _check_has_nodes(
        table.key("displacement_face"), probe.displacement_face, probe.displacement_x, mesh, split
    )
    if options["output_interval"] > end_time:
        raise InputError("output.interval", f"is longer than solver.end_time ({end_time:g} s)")
    constrained_faces = {m.face for m in motions}
    if probe.reaction_face not in constrained_faces:
        raise InputError(
            "output.reaction_face",
            f"{probe.reaction_face!r} is neither clamped nor prescribed; a reaction force exists "
            f"only there ({', '.join(sorted(constrained_faces))})",
        )
    return options, probe


def _materials(root: _Root) -> tuple[dict[str, PlyMaterial], dict[str, PlyFailure]]:
    """Ply materials, and the failure data ([materials.NAME.failure]) of those that have it."""
    data = root.data.get("materials")
    if data is None:
        raise InputError("materials", "missing (define at least one [materials.NAME])")
    if not isinstance(data, dict) or not data:
        raise InputError("materials", "define at least one material ([materials.NAME])")
    elastic_schema, failure_schema = section("materials.NAME"), section("materials.NAME.failure")
    materials, failures = {}, {}
    for name, values in data.items():
        if _name(name) != name:
            raise InputError(
                f"materials.{_name(name)}", "a material name is letters, digits, _ and - only"
            )
        table = _Table(f"materials.{name}", values, elastic_schema, root.reading)
        elastic = {k.name: table.number(k.name) for k in elastic_schema.keys if k.kind == "float"}
        materials[name] = PlyMaterial(name=name, **elastic)
        failure = table.table("failure")
        if failure is not None:
            strengths = {k.name: failure.number(k.name) for k in failure_schema.keys}
            failures[name] = PlyFailure(name=name, **strengths)
    return materials, failures


def _laminate(table: _Table, materials: dict[str, PlyMaterial]) -> Laminate:
    """[laminate]: plies bottom to top, as material + ply_thickness (mm) + angles (degrees),
    or as plies = [{material, angle, thickness}, ...]."""

    def material(key: str, name: str) -> PlyMaterial:
        if name not in materials:
            raise InputError(key, f"unknown material {name!r} (defined: {', '.join(materials)})")
        return materials[name]

    if table.has("plies"):
        for name in ("material", "angles", "ply_thickness"):
            if table.has(name):
                raise InputError(table.key(name), "give either plies, or material + angles")
        ply_tables = table.tables("plies")
        if not ply_tables:
            raise InputError(table.key("plies"), "needs at least one ply")
        plies = [
            Ply(
                material(t.key("material"), t.string("material")),
                t.number("angle"),
                t.number("thickness"),
            )
            for t in ply_tables
        ]
    else:
        for name in ("material", "ply_thickness", "angles"):
            if not table.has(name):
                raise InputError(table.key(name), "missing (or give plies = [...])")
        mat = material(table.key("material"), table.string("material"))
        thickness = table.number("ply_thickness")
        plies = [Ply(mat, a, thickness) for a in table.numbers("angles")]
    if len(plies) > MAX_PLIES:
        raise InputError(
            table.key("plies" if table.has("plies") else "angles"),
            f"{len(plies)} plies, more than {MAX_PLIES} (group them into sublaminates)",
        )
    return Laminate(tuple(plies))


def _mesh(table: _Table, kind: ModelKind, laminate: Laminate, source: str) -> MeshConfig:
    """[mesh]: the plate (mm) and its cells in-plane, or a shell (``settings.shells``), and
    the plies of each mesh layer (one layer of all plies unless the model is layerwise)."""
    mesh_kind = table.choice("kind")
    refuse_other_keys(table, mesh_kind)
    shell = None
    if mesh_kind == MeshKind.PLATE:
        for name in KIND_KEYS[MeshKind.PLATE][0]:
            if not table.has(name):
                raise InputError(table.key(name), 'missing (kind = "plate" needs it)')
        length, width = table.number("length"), table.number("width")
        nx, ny = table.integer("nx"), table.integer("ny")
    else:
        shell = shell_shape(table, mesh_kind, source)
        length = width = 0.0
        nx = ny = 0
    if kind == ModelKind.LAYERWISE:
        layers = table.integers("layers", unique=False)
        if layers is None:
            layers = (1,) * laminate.n_plies
        if not layers:
            raise InputError(table.key("layers"), "must list the plies of each mesh layer")
        if sum(layers) != laminate.n_plies:
            raise InputError(
                table.key("layers"),
                f"groups {sum(layers)} plies but the laminate has {laminate.n_plies}",
            )
    else:
        if table.has("layers"):
            raise InputError(table.key("layers"), "only a layerwise model has mesh layers")
        layers = (laminate.n_plies,)
    rebalance = table.number("rebalance")
    if 0.0 < rebalance <= 1.0:
        raise InputError(
            table.key("rebalance"),
            f"is the imbalance (the costliest rank's cost over the mean, >= 1) that re-cuts "
            f"the partition: > 1, or 0 for never (got {rebalance})",
        )
    return MeshConfig(
        length, width, nx, ny, tuple(layers), table.choice("partition"), shell, rebalance
    )


def _check_geometry(mesh: MeshConfig, laminate: Laminate) -> None:
    """Degenerate cells are refused before meshing: each cell side at least MIN_LENGTH, the
    longest at most MAX_ASPECT x the shortest, and the plies of a cell alike."""
    dx, dy = mesh.length / mesh.nx, mesh.width / mesh.ny
    for name, size in (("nx", dx), ("ny", dy)):
        if size < MIN_LENGTH:
            raise InputError(
                f"mesh.{name}",
                f"cells {size:.3g} mm long, below the smallest cell size {MIN_LENGTH:g} mm",
            )
    plies = laminate.plies
    start = 0
    for k, count in enumerate(mesh.layers):
        layer = plies[start : start + count]
        start += count
        height = sum(p.thickness for p in layer)
        sides = {"nx": dx, "ny": dy, "laminate": height}
        longest, shortest = max(sides, key=sides.get), min(sides, key=sides.get)
        if sides[longest] > MAX_ASPECT * sides[shortest]:
            # more cells along a long side, or fewer along a short one
            key = f"mesh.{longest}" if longest != "laminate" else f"mesh.{shortest}"
            raise InputError(
                key,
                f"cells of {dx:.4g} x {dy:.4g} x {height:.4g} mm (cell layer {k}): the longest "
                f"side is more than {MAX_ASPECT:g} x the shortest (a degenerate element)",
            )
        thick = [p.thickness for p in layer]
        if max(thick) > MAX_ASPECT * min(thick):
            raise InputError(
                "laminate",
                f"plies of {min(thick):.3g} and {max(thick):.3g} mm in one cell layer: the "
                f"thickest is more than {MAX_ASPECT:g} x the thinnest",
            )


def _x_range(table: _Table, mesh: MeshConfig, name: str = "x") -> tuple[float, float] | None:
    """Optional x selection of a face's nodes (mm): ``x`` for one line of nodes across the
    width (it must be a node line of the mesh), or ``x_min`` and ``x_max`` for a pad."""
    if table.has(name):
        if name == "x" and (table.has("x_min") or table.has("x_max")):
            raise InputError(table.key(name), "give either x, or x_min and x_max")
        if not mesh.structured:  # any x: the nodes within round-off of it
            x = table.number(name)
            return (x, x)
        x = table.number(name, 0.0, mesh.length)
        cells = x / mesh.length * mesh.nx
        if abs(cells - round(cells)) > 1e-6:
            raise InputError(
                table.key(name),
                f"x = {x} mm is not on a node line (cells are {mesh.length / mesh.nx:g} mm long)",
            )
        return (x, x)
    if name != "x" or not (table.has("x_min") or table.has("x_max")):
        return None
    for end in ("x_min", "x_max"):
        if not table.has(end):
            raise InputError(table.key(end), "missing (a pad needs both x_min and x_max)")
    if mesh.structured:
        table.number("x_min", 0.0, mesh.length)
        table.number("x_max", 0.0, mesh.length)
    return table.range("x_min", "x_max")


def _check_holds_centroids(
    table: _Table, mesh: MeshConfig, low: float, high: float, axis: str = "x"
) -> None:
    """A range of cell centroids along ``axis`` ("x" or "y") must hold at least one (else it
    would do nothing), and a bound given must lie on the mesh (one beyond its edge was cut off
    without a word: left out, a bound reaches the edge)."""
    if not mesh.structured:  # a shell's cells are known when its mesh is built
        return
    size, count = (mesh.length, mesh.nx) if axis == "x" else (mesh.width, mesh.ny)
    h = size / count
    for end, value in ((f"{axis}_min", low), (f"{axis}_max", high)):
        if table.has(end) and not -1e-9 * size <= value <= size * (1.0 + 1e-9):
            raise InputError(
                table.key(end),
                f"{value:g} mm lies beyond the mesh ({axis} from 0 to {size:g} mm); leave it "
                "out for a region that reaches the edge",
            )
    first = math.ceil(max(low, 0.0) / h - 0.5 - 1e-9)  # first centroid (i + 1/2) h >= low
    if first >= count or (first + 0.5) * h > high + 1e-9 * h:
        upper = f"{axis}_max"
        raise InputError(
            table.key(upper if table.has(upper) else f"{axis}_min"),
            f"the range [{low:g}, {high:g}] mm holds no cell centroid along {axis} (cells are "
            f"{h:g} mm {'long' if axis == 'x' else 'wide'})",
        )


def _split_boundaries(
    kind: ModelKind, mesh: MeshConfig, interfaces: Interfaces
) -> tuple[bool, ...]:
    """Which boundaries between mesh layers have their own nodes on each side (layerwise
    delamination), as ``simulation.build_structure`` meshes them."""
    boundaries = list(itertools.accumulate(mesh.layers))[:-1]
    if kind != ModelKind.LAYERWISE:
        return (False,) * len(boundaries)
    return tuple(b in interfaces.delaminate for b in boundaries)


# Node sets of faces on the structured mesh, exactly: a face's nodes are those with the node-line
# index along x in an interval, along y in an interval, and one of a set of node levels through
# the thickness (level j, and at a split boundary which side's copy).
_NodeBox = tuple[tuple[int, int], tuple[int, int], frozenset]


def _face_box(part: str, mesh: MeshConfig, split: tuple[bool, ...]) -> _NodeBox:
    n_layers = len(mesh.layers)

    def bottom(k: int) -> tuple[int, str]:
        return (k, "above" if k > 0 and split[k - 1] else "")

    def top(k: int) -> tuple[int, str]:
        return (k + 1, "below" if k < n_layers - 1 and split[k] else "")

    xs, ys = (0, mesh.nx), (0, mesh.ny)
    name, _, layer = part.partition("_layer")
    layers = range(n_layers) if not layer else [int(layer)]
    if name == "bottom":
        levels = {bottom(layers[0] if layer else 0)}
    elif name == "top":
        levels = {top(layers[0] if layer else n_layers - 1)}
    else:
        levels = {level for k in layers for level in (bottom(k), top(k))}
        if name == "x0":
            xs = (0, 0)
        elif name == "x1":
            xs = (mesh.nx, mesh.nx)
        elif name == "y0":
            ys = (0, 0)
        else:
            ys = (mesh.ny, mesh.ny)
    return xs, ys, frozenset(levels)


def _nodes_box(
    face: str, x_range: tuple[float, float] | None, mesh: MeshConfig, split: tuple[bool, ...]
) -> _NodeBox | None:
    """The node set of ``face`` (a&b: common nodes) restricted to ``x_range``; None if empty."""
    xs, ys, levels = (0, mesh.nx), (0, mesh.ny), None
    for part in face.split("&"):
        (x0, x1), (y0, y1), lv = _face_box(part, mesh, split)
        xs, ys = (max(xs[0], x0), min(xs[1], x1)), (max(ys[0], y0), min(ys[1], y1))
        levels = lv if levels is None else levels & lv
    if x_range is not None:
        dx = mesh.length / mesh.nx
        tol = 1e-6 * mesh.length  # as loading.face_nodes selects them
        low = max(xs[0], math.ceil((x_range[0] - tol) / dx))
        high = min(xs[1], math.floor((x_range[1] + tol) / dx))
        xs = (low, high)
    if xs[0] > xs[1] or ys[0] > ys[1] or not levels:
        return None
    return xs, ys, levels


def _check_has_nodes(key: str, face: str, x_range, mesh: MeshConfig, split) -> None:
    if not mesh.structured:  # a shell's faces are checked when its mesh is built
        return
    if _nodes_box(face, x_range, mesh, split) is None:
        where = f" with x in [{x_range[0]:g}, {x_range[1]:g}] mm" if x_range is not None else ""
        raise InputError(
            key, f"{face!r}{where} holds no node (a&b: the nodes on both faces; these share none)"
        )


def _check_motions_agree(motions: list[PrescribedMotion], mesh: MeshConfig, split) -> None:
    """Two motions of the same component on faces that share nodes must agree there: a clamp
    and a prescribed motion (or two prescribed motions) on one DOF are refused, naming both."""
    boxes = [_nodes_box(m.face, m.x_range, mesh, split) for m in motions]
    for j, b in enumerate(motions):
        for i in range(j):
            a = motions[i]
            if a.component != b.component or a.key == b.key or a == b:
                continue
            if _is_zero_motion(a) and _is_zero_motion(b):
                continue  # both hold the shared nodes at zero: no conflict
            (ax, ay, al), (bx, by, bl) = boxes[i], boxes[j]
            if (
                max(ax[0], bx[0]) <= min(ax[1], bx[1])
                and max(ay[0], by[0]) <= min(ay[1], by[1])
                and al & bl
            ):
                raise InputError(
                    b.key,
                    f"{b.face!r} shares nodes with {a.key} = {a.face!r} and both prescribe "
                    f"component {b.component} there, differently (a node can follow only one)",
                )


def _symmetry_motions(kind: ModelKind, mesh: MeshConfig, interfaces: Interfaces) -> list:
    """The u_z = 0 motions ``simulation.build_structure`` adds at a layerwise model's symmetry
    interfaces (an adaptive model holds its extra nodes there instead)."""
    if kind != ModelKind.LAYERWISE:
        return []
    boundaries = list(itertools.accumulate(mesh.layers))[:-1]
    return [
        PrescribedMotion(
            f"top_layer{boundaries.index(i)}",
            "z",
            MotionKind.DISPLACEMENT,
            0.0,
            Amplitude.constant(0.0),
            key="interfaces.symmetry",
        )
        for i in interfaces.symmetry
    ]


def _is_zero_motion(motion: PrescribedMotion) -> bool:
    return motion.value == 0.0 or all(v == 0.0 for v in motion.amplitude.values)


def _interfaces(
    root: _Root, kind: ModelKind, laminate: Laminate, mesh: MeshConfig
) -> tuple[Interfaces, tuple[Manual, ...], CohesiveLaw | None]:
    """[interfaces] (which ply interfaces refine, delaminate, are symmetry planes), then the
    [[refinement]] tables and the [cohesive] law that depend on it."""
    n_plies = laminate.n_plies
    table = root.table("interfaces")
    refinement_tables = root.tables("refinement")
    cohesive_table = root.table("cohesive")
    if table is None:
        if kind == ModelKind.ADAPTIVE:
            raise InputError("interfaces", "an adaptive model needs [interfaces] (refine = ...)")
        if refinement_tables:
            raise InputError("refinement", "only an adaptive model refines")
        if cohesive_table is not None:
            raise InputError("cohesive", "no interface delaminates ([interfaces] delaminate)")
        return Interfaces(), (), None
    if kind == ModelKind.ESL:
        raise InputError("interfaces", "an ESL model has no interfaces to refine (use adaptive)")
    if n_plies < 2:
        raise InputError("interfaces", "a laminate of one ply has no interfaces")
    interfaces = Interfaces(
        refine=tuple(sorted(table.integers("refine", high=n_plies - 1))),
        delaminate=tuple(sorted(table.integers("delaminate", high=n_plies - 1))),
        symmetry=tuple(sorted(table.integers("symmetry", high=n_plies - 1))),
        initial=table.choice("initial"),
    )
    if kind == ModelKind.LAYERWISE:
        _check_layerwise_interfaces(interfaces, mesh)
        if refinement_tables:
            raise InputError("refinement", "only an adaptive model refines")
    else:
        _check_adaptive_interfaces(interfaces)
    if set(interfaces.symmetry) & set(interfaces.delaminate):
        raise InputError("interfaces.symmetry", "a symmetry interface cannot also delaminate")
    if interfaces.symmetry and not mesh.structured:
        raise InputError(
            "interfaces.symmetry",
            "holds u_z = 0 there, a symmetry plane of a flat plate only; on a shell model the "
            "whole laminate (its normal is not along z)",
        )
    refinements = tuple(_refinement(t, interfaces, n_plies, mesh) for t in refinement_tables)
    return interfaces, refinements, _cohesive(cohesive_table, interfaces)


def _check_layerwise_interfaces(interfaces: Interfaces, mesh: MeshConfig) -> None:
    """A layerwise model does not refine; it delaminates (or holds symmetric) only at the
    boundaries between its mesh layers."""
    boundaries = list(itertools.accumulate(mesh.layers))[:-1]
    if interfaces.refine or interfaces.initial != Refinement.NONE:
        key = "interfaces.refine" if interfaces.refine else "interfaces.initial"
        raise InputError(key, "a layerwise model does not refine (its layers are fixed)")
    for name, values in (("delaminate", interfaces.delaminate), ("symmetry", interfaces.symmetry)):
        for value in values:
            if value not in boundaries:
                raise InputError(
                    f"interfaces.{name}",
                    f"interface {value} is not a boundary between mesh layers "
                    f"(mesh.layers puts them at {boundaries})",
                )


def _check_adaptive_interfaces(interfaces: Interfaces) -> None:
    """An adaptive model refines some interface, and its symmetry interfaces are among them."""
    allowed = set(interfaces.refine) | set(interfaces.delaminate)
    for value in interfaces.symmetry:
        if value not in allowed:
            raise InputError("interfaces.symmetry", f"interface {value} is not listed to refine")
    if not allowed:
        raise InputError("interfaces.refine", "an adaptive model needs interfaces to refine")


def _refinement(table: _Table, interfaces: Interfaces, n_plies: int, mesh: MeshConfig) -> Manual:
    """One [[refinement]]: interfaces refined at a time (s) or a probe displacement (mm), in
    an x range of cell centroids (mm); strongly only where [interfaces] lets them delaminate."""
    if table.has("time") == table.has("displacement"):
        raise InputError(table.key("time"), "give exactly one trigger: time (s) or displacement")
    time = table.number("time") if table.has("time") else math.inf
    displacement = table.number("displacement") if table.has("displacement") else math.inf
    chosen = table.integers("interfaces", high=n_plies - 1)
    if not chosen:
        raise InputError(table.key("interfaces"), "list the interfaces to refine")
    kind = table.choice("kind")
    delaminate = interfaces.delaminate
    pool = delaminate if kind == Refinement.STRONG else set(interfaces.refine) | set(delaminate)
    for value in chosen:
        if value not in pool:
            raise InputError(
                table.key("interfaces"),
                f"interface {value} may not refine {kind}ly (see [interfaces])",
            )
    x_min, x_max = table.range("x_min", "x_max", strict=True)
    _check_holds_centroids(table, mesh, x_min, x_max)
    return Manual(tuple(sorted(chosen)), kind.state, time, displacement, x_min, x_max)


def _cohesive(table: _Table | None, interfaces: Interfaces) -> CohesiveLaw | None:
    """[cohesive]: the traction-separation law, needed exactly when an interface delaminates."""
    if not interfaces.delaminate:
        if table is not None:
            raise InputError("cohesive", "no interface delaminates ([interfaces] delaminate)")
        return None
    if table is None:
        raise InputError("cohesive", "interfaces delaminate but [cohesive] is missing")
    numbers = {k.name: table.number(k.name) for k in table.schema.keys if k.kind == "float"}
    return CohesiveLaw(law=table.choice("law"), **numbers)


def _impactor(root: _Root) -> Impactor | None:
    """[impactor]: a rigid body (mm, tonne, mm/s) hitting the top face, or None."""
    table = root.table("impactor")
    if table is None:
        return None
    return Impactor(
        shape=table.choice("shape"),
        radius=table.number("radius"),
        mass=table.number("mass"),
        position=table.numbers("position"),
        velocity=table.numbers("velocity"),
        penalty=table.number("penalty"),
        friction=table.number("friction"),
    )


# names a [[rigid]] body cannot take: its history columns <name>_force, <name>_displacement
# would be those of the impactor, the reaction, the applied load, the contact or the MMB lever
RESERVED_BODY_NAMES = ("impactor", "reaction", "applied", "contact", "lever", "hinge")


def _rigid_bodies(root: _Root) -> tuple[RigidBody, ...]:
    """[[rigid]]: rigid loading bodies, each fixed, prescribed (with a time curve) or free
    (with a mass), named uniquely."""
    bodies: list[RigidBody] = []
    for table in root.tables("rigid"):
        name = table.string("name")
        if not name.isidentifier() or name in RESERVED_BODY_NAMES:
            raise InputError(
                table.key("name"),
                f"{name!r}: letters, digits and _ (not starting with a digit), none of "
                f"{', '.join(RESERVED_BODY_NAMES)} (their history columns are taken)",
            )
        if any(body.name == name for body in bodies):
            raise InputError(table.key("name"), f"{name!r} names another [[rigid]] body too")
        motion = RigidMotion(table.choice("motion"))
        allowed = {
            RigidMotion.FIXED: set(),
            RigidMotion.PRESCRIBED: {"velocity", "displacement", "rise_time", "profile", "curve"},
            RigidMotion.FREE: {"mass", "velocity"},
            RigidMotion.LEVER: set(),
        }[motion]
        for key in ("mass", "velocity", "displacement", "rise_time", "profile", "curve"):
            if table.has(key) and key not in allowed:
                raise InputError(table.key(key), f"does not apply to a {motion} body")
        shape = ImpactorShape(table.choice("shape"))
        if shape != ImpactorShape.CYLINDER and table.has("axis"):
            raise InputError(table.key("axis"), f"a {shape} has no axis (only a cylinder has)")
        plane = shape == ImpactorShape.PLANE
        for key, needed in (("radius", not plane), ("normal", plane)):
            if needed and not table.has(key):
                raise InputError(table.key(key), f"missing (a {shape} needs its {key})")
            if table.has(key) and not needed:
                raise InputError(table.key(key), f"does not apply to a {shape}")
        normal = table.numbers("normal")
        if normal is not None and not any(normal):
            raise InputError(table.key("normal"), "is the zero vector: give the plane's normal")
        if table.number("friction") > 0.0 and table.choice("face") == "all":
            raise InputError(
                table.key("friction"),
                'friction on face = "all" is not supported yet (the extra nodes of refined cells '
                'carry no tangential springs): use face = "top" or "bottom", or no friction',
            )
        amplitude = Amplitude.constant(1.0)
        if motion == RigidMotion.PRESCRIBED:
            if table.has("velocity") == table.has("displacement"):
                raise InputError(
                    table.key("velocity"), "a prescribed body takes a velocity or a displacement"
                )
            amplitude = _amplitude(table)
        if motion == RigidMotion.FREE and not table.has("mass"):
            raise InputError(table.key("mass"), "missing (a free body needs its mass)")
        bodies.append(
            RigidBody(
                name=name,
                shape=shape,
                radius=table.number("radius") if table.has("radius") else 0.0,
                position=table.numbers("position"),
                face=table.choice("face"),
                motion=motion,
                axis=table.choice("axis"),
                mass=table.number("mass") if table.has("mass") else math.inf,
                velocity=table.numbers("velocity") or (0.0, 0.0, 0.0),
                displacement=table.numbers("displacement"),
                amplitude=amplitude,
                penalty=table.number("penalty"),
                friction=table.number("friction"),
                normal=normal,
            )
        )
    return tuple(bodies)


def _lever(root: _Root, bodies: tuple[RigidBody, ...], faces: list[str]) -> Lever | None:
    """[lever]: the loading lever of an MMB test, on the [[rigid]] saddle it names (motion
    "lever"; no other body may have that motion)."""
    carried = [body.name for body in bodies if body.motion == RigidMotion.LEVER]
    table = root.table("lever")
    if table is None:
        if carried:
            raise InputError(
                f"rigid.{carried[0]}.motion", '"lever" needs a [lever] table that carries it'
            )
        return None
    saddle = table.string("saddle")
    named = [body for body in bodies if body.name == saddle]
    if not named:
        known = ", ".join(body.name for body in bodies) or "none"
        raise InputError(table.key("saddle"), f"{saddle!r} is no [[rigid]] body (known: {known})")
    if named[0].shape == ImpactorShape.PLANE:
        raise InputError(f"rigid.{saddle}.shape", "the lever's saddle is a sphere or a cylinder")
    if named[0].motion != RigidMotion.LEVER:
        raise InputError(
            f"rigid.{saddle}.motion",
            f'the lever\'s saddle has motion = "{named[0].motion}"; give it motion = "lever"',
        )
    others = [name for name in carried if name != saddle]
    if others:
        raise InputError(f"rigid.{others[0]}.motion", "one lever carries one saddle: "
                         f"{saddle!r} (a second lever body is not supported)")  # fmt: skip
    if table.has("velocity") == table.has("displacement"):
        raise InputError(
            table.key("velocity"), "the load point takes a velocity or a displacement (one)"
        )
    return Lever(
        saddle=saddle,
        hinge=table.face("hinge", faces),
        load_arm=table.number("load_arm"),
        displacement=table.number("displacement") if table.has("displacement") else None,
        velocity=table.number("velocity") if table.has("velocity") else None,
        amplitude=_amplitude(table),
    )


def _stabilisation(root: _Root, kind: ModelKind) -> Stabilisation:
    """[stabilisation] of an adaptive model after refinement: damping (1/s) and windows (s)."""
    table = root.table("stabilisation")
    if table is None:
        return Stabilisation()
    if kind != ModelKind.ADAPTIVE:
        raise InputError("stabilisation", "only an adaptive model refines, so only it stabilises")
    damping = table.number("damping")
    window = table.number("damping_window")
    release = table.number("release_window")
    if (damping > 0.0) != (window > 0.0):
        raise InputError(
            "stabilisation.damping_window",
            "damping after weak refinement needs both damping (1/s) and damping_window (s)",
        )
    return Stabilisation(damping, window, release, table.boolean("equilibrate"))


def _interface_stress(given: float | None, interfaces: Interfaces) -> float | None:
    """[indicators] interface_stress as the run uses it: the given fraction, off for 0, and
    ``DEFAULT_INTERFACE_STRESS`` where it is not given and an interface may delaminate."""
    if given is None:
        return DEFAULT_INTERFACE_STRESS if interfaces.delaminate else None
    return given if given > 0.0 else None


def _indicators(root: _Root, kind: ModelKind, interfaces: Interfaces) -> IndicatorSettings | None:
    """[indicators] of an adaptive model: which refinement indicators run, and how often."""
    table = root.table("indicators")
    if table is None:
        return None
    if kind != ModelKind.ADAPTIVE:
        raise InputError("indicators", "only an adaptive model refines")
    settings = IndicatorSettings(
        interval=table.number("interval"),
        ply_failure=table.number("ply_failure"),
        interface_stress=_interface_stress(table.number("interface_stress"), interfaces),
        matrix_damage=table.boolean("matrix_damage"),
        spread=table.integer("spread"),
        strong_after=table.number("strong_after"),
        front_distance=table.number("front_distance"),
        look_ahead=table.boolean("look_ahead"),
    )
    if not interfaces.delaminate:
        for name, used in (
            (IndicatorKind.FRONT_DISTANCE, bool(settings.front_distance)),
            (IndicatorKind.STRONG_AFTER, settings.strong_after is not None),
            (IndicatorKind.INTERFACE_STRESS, settings.interface_stress is not None),
            (IndicatorKind.MATRIX_DAMAGE, settings.matrix_damage),
        ):
            if used:
                raise InputError(
                    f"indicators.{name}", "no interface may delaminate ([interfaces] delaminate)"
                )
    front = bool(interfaces.delaminate) and settings.front_distance != 0.0
    if (
        settings.ply_failure is None
        and settings.interface_stress is None
        and not settings.matrix_damage
        and not front
    ):
        raise InputError(
            "indicators",
            "switch on at least one indicator (ply_failure, interface_stress, matrix_damage, "
            "or the front of a delaminable interface)",
        )
    return settings


def _amplitude(table: _Table) -> Amplitude:
    """The time curve of a prescribed motion or a load: a curve, or rise_time (s) + profile."""
    if table.has("curve"):
        for name in ("rise_time", "profile"):
            if table.has(name):
                raise InputError(table.key(name), "give either curve, or rise_time + profile")
        times, scales = table.curve("curve")
        return Amplitude(times, scales)
    if not table.has("rise_time"):
        raise InputError(table.key("rise_time"), "missing (give rise_time, or a curve)")
    rise_time = table.number("rise_time")
    profile = table.choice("profile")
    return Amplitude.ramp(rise_time, smooth=profile == Profile.SMOOTH)


# ------------------------------------------------------------------------ run size and cost
@dataclass(frozen=True)
class ModelSize:
    """Size of the base mesh of a config (before any refinement)."""

    cells: int
    nodes: int
    plies: int
    cell_layers: int

    @property
    def dofs(self) -> int:
        return 3 * self.nodes


def model_size(mesh: MeshConfig, laminate: Laminate, split: int = 0) -> ModelSize:
    """Cells, nodes, plies and cell layers of the mesh ``simulation.build_structure`` makes
    (``split``: layer boundaries with their own nodes on each side)."""
    layers = len(mesh.layers)
    if mesh.structured:
        cells = mesh.nx * mesh.ny * layers
        nodes = (mesh.nx + 1) * (mesh.ny + 1) * (layers + 1 + split)
    else:  # about a node per quadrilateral and level (a closed surface: exactly)
        cells = mesh.shell.quads * layers
        nodes = mesh.shell.quads * (layers + 1 + split)
    return ModelSize(cells, nodes, laminate.n_plies, layers)


# Peak memory (resident set, one rank) of an unrefined run, measured here on ESL plates (the
# plate-impact material, 4 and 16 plies) of 20 x 20 and 200 x 200 cells: 286 MB at 400 cells
# (16 plies), 365 MB at 40 000 cells with 4 plies and 372 MB with 16 plies, i.e. 2.0 kB per
# cell and 16 B per (cell x ply) above the base.
MEMORY_BASE_BYTES = 2.9e8  # the interpreter, DOLFINx, numba and the compiled forms
MEMORY_PER_CELL_BYTES = 2.0e3
MEMORY_PER_CELL_PLY_BYTES = 16.0
# Step time, measured on this 2-vCPU machine: a fixed part (the solver's own work and the
# vectors' exchanges: 70 us on a 90-cell DCB), then 0.44 us per elastic cell, rounded up to
# 0.5 (the impact plate's ESL run, 2500 cells of 16 plies: 1.11 ms a step), 0.6 us per
# cohesive element (its layerwise run, 10 000 cells and 7500 cohesive elements: 9.9 ms), and
# with ply damage about 1.1 us per (cell x ply) on top (the numba kernel: 8.6 us a cell of 8
# plies). The estimate once took 10 us per cell (+0.3 per ply), ten times a run's: a layerwise
# ENF of 2.5 min was announced at 21 min. Good to a factor of ~2 on an idle machine.
STEP_SECONDS_FIXED = 7.0e-5
STEP_SECONDS_PER_CELL = 5.0e-7
STEP_SECONDS_PER_COHESIVE = 6.0e-7
STEP_SECONDS_PER_DAMAGED_PLY = 1.1e-6


def estimated_memory(size: ModelSize, ranks: int = 1) -> float:
    """Estimated peak memory of a run in bytes, over all ``ranks``, of the unrefined model (an
    adaptive model's refined cells add their extra nodes and subelements).

    Parameters:
        size: the model size (``model_size``).
        ranks: MPI ranks (each holds its own interpreter and compiled forms).
    """
    return (
        ranks * MEMORY_BASE_BYTES
        + MEMORY_PER_CELL_BYTES * size.cells
        + MEMORY_PER_CELL_PLY_BYTES * size.cells * size.plies
    )


def estimated_step_seconds(
    size: ModelSize, ranks: int = 1, ply_damage: bool = False, cohesive_elements: int = 0
) -> float:
    """Estimated wall time (s) of one time step of the unrefined model on ``ranks`` ranks
    (refined cells cost 3 .. 7 x an unrefined one); ``ply_damage``: every ply of every cell
    runs the damage law; ``cohesive_elements``: those of the model as built (a layerwise
    model's, an insert film's)."""
    per_cell = STEP_SECONDS_PER_CELL
    if ply_damage:
        per_cell += STEP_SECONDS_PER_DAMAGED_PLY * size.plies / max(size.cell_layers, 1)
    work = size.cells * per_cell + cohesive_elements * STEP_SECONDS_PER_COHESIVE
    return STEP_SECONDS_FIXED + work / ranks


def step_count(end_time: float, time_step: float) -> int | float:
    """The number of steps a run takes to reach ``end_time`` with ``time_step`` (both s):
    ceil(end_time / time_step) up to round-off; math.inf if it overflows."""
    ratio = end_time / time_step
    if not math.isfinite(ratio):
        return math.inf
    return math.ceil(ratio - 1e-9)


def check_step_count(solver: SolverSettings, time_step: float) -> int:
    """The run's step count (``step_count``), refused above ``solver.max_steps``.

    Raises:
        InputError: on ``solver.max_steps``, with the count and the step.
    """
    steps = step_count(solver.end_time, time_step)
    if steps > solver.max_steps:
        count = str(steps) if steps < 1e15 else f"{steps:.3g}" if steps < math.inf else "over 1e308"
        raise InputError(
            "solver.max_steps",
            f"the run would take {count} steps of {time_step:.4g} s to solver.end_time = "
            f"{solver.end_time:g} s, above solver.max_steps = {solver.max_steps} (raise it, or "
            "shorten end_time)",
        )
    return steps


def output_counts(solver: SolverSettings, time_step: float) -> tuple[int, int]:
    """History rows and field frames a run writes at a constant ``time_step`` (s): one at t = 0
    and one at the first step at or after each further output time, at most one per step."""
    steps = step_count(solver.end_time, time_step)
    duration = steps * time_step

    def count(interval: float | None) -> int:
        if not interval:
            return 0
        return int(min(steps + 1, math.floor(duration / interval + 1e-9) + 1))

    return count(solver.output_interval), count(solver.field_interval)
