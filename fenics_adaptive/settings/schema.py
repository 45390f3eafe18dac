"""Every section and key of a run configuration, declared once: name, type, unit, default, bounds
and a one-line description.

The parser (``fenics_adaptive.settings.config``) reads every key through this table (its unknown-key
check and its typed accessors use it), and ``reference_markdown()`` renders it for the
documentation, so the two cannot drift apart. This module imports neither DOLFINx nor numba (the
documentation build and ``--help`` use it).

Units: N, mm, s, tonne (stress and moduli MPa, density tonne/mm^3, energy mJ, fracture energy
N/mm, cohesive penalty N/mm^3).

Bounds. Every number must be finite. Besides the physical bounds (a length > 0, a Poisson's
ratio in (-1, 1), ...), lengths, forces and speeds have sanity bounds far beyond any model this
code is made for (a length up to 1e5 mm, a force up to 1e12 N, a speed up to 1e8 mm/s): a value
beyond them is a typing slip, and it would overflow the arithmetic of a run.

Unit plausibility. Densities, moduli, strengths, fracture energies and cohesive penalties have a
*plausible* range for engineering solids (``Key.plausible``). A value outside it is refused with
the value the usual unit slip would give (kg/m^3 for tonne/mm^3, Pa or GPa for MPa, J/m^2 for
N/mm, N/m^3 for N/mm^3), e.g. ``materials.cfrp.rho: 1600 tonne/mm^3 is implausible for a solid
(expected 5e-10 .. 2.5e-08); did you mean 1.6e-09 (kg/m^3 -> tonne/mm^3)?``. One switch,
``[model] check_units = false``, accepts unusual materials (foams, rubbers, an unusual penalty):
one switch in one place rather than a flag per material, because the check also covers the
cohesive law and the failure data, which are not materials, and because a file that turns it
off says so where every reader of the file looks first.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from fenics_adaptive.settings.kinds import (
    ImpactorShape,
    Kinematics,
    MassScaling,
    MaterialAxis,
    MeshKind,
    MixedModeLaw,
    ModelKind,
    Partition,
    Profile,
    Refinement,
    RigidMotion,
    SurfaceReference,
    ThicknessIntegration,
)

# the default [mesh] rebalance: the imbalance (costliest rank over the mean) that re-cuts the
# partition of an adaptive run on several ranks (``parallel.balance``)
REBALANCE = 1.2

# --------------------------------------------------------------------------- limits (documented)
MAX_LENGTH = 1.0e5  # mm: largest length, width, ply thickness, radius, coordinate
MIN_LENGTH = 1.0e-4  # mm: smallest cell size or ply thickness (Gmsh's tolerance is 1e-8 mm)
MAX_ASPECT = 1.0e4  # largest ratio of a cell's longest to its shortest side (and of plies)
MAX_FORCE = 1.0e12  # N: largest force component
MAX_PRESSURE = 1.0e7  # MPa: largest pressure (10 TPa, far above any material's strength)
MAX_DISPLACEMENT = 1.0e5  # mm: largest prescribed displacement
MAX_SPEED = 1.0e8  # mm/s: largest prescribed or impactor velocity component
MAX_TIME = 1.0e6  # s: largest time in a time curve, rise time or trigger
MAX_RINGS = 1000  # largest number of rings of neighbours (indicators.spread, front)
MAX_PLIES = 256  # most plies in a laminate (the compiled forms grow with them)
DEFAULT_MAX_STEPS = 10**9  # solver.max_steps
DEFAULT_MAX_MEMORY_GB = 16.0  # model.max_memory


class _Required:
    def __repr__(self) -> str:
        return "required"


REQUIRED = _Required()  # a key without a default that must be given
OPTIONAL = None  # a key without a default that may be left out


# The usual unit slips of a quantity: (unit the value was probably given in, factor that turns
# it into this code's unit).
UNIT_SLIPS: dict[str, tuple[tuple[str, str, float], ...]] = {
    "density": (("kg/m^3", "tonne/mm^3", 1e-12), ("g/cm^3", "tonne/mm^3", 1e-9)),
    "modulus": (("Pa", "MPa", 1e-6), ("GPa", "MPa", 1e3)),
    "strength": (("Pa", "MPa", 1e-6), ("kPa", "MPa", 1e-3)),
    "fracture energy": (("J/m^2", "N/mm", 1e-3),),
    "fibre fracture energy": (("J/m^2", "N/mm", 1e-3),),
    "penalty": (("N/m^3", "N/mm^3", 1e-9), ("MN/m^3", "N/mm^3", 1e-3)),
}
# Plausible ranges for engineering solids (in this code's units).
PLAUSIBLE = {
    "density": (5e-10, 2.5e-8),  # tonne/mm^3: 500 .. 25 000 kg/m^3
    "modulus": (5e2, 1.2e6),  # MPa: 0.5 GPa (polymers) .. 1200 GPa (diamond)
    "strength": (1.0, 1.0e4),  # MPa
    "fracture energy": (1e-2, 50.0),  # N/mm: 10 J/m^2 .. 50 kJ/m^2
    # N/mm: breaking fibres costs more (carbon/epoxy 50 .. 200 kJ/m^2, Pinho et al. 2006)
    "fibre fracture energy": (1.0, 1.0e3),
    "penalty": (1e2, 1e9),  # N/mm^3
}


@dataclass(frozen=True)
class Key:
    """One config key.

    ``kind``: "float", "int", "bool", "choice", "string", "face" (a face name or faces joined
    by &), "floats" (a list of numbers, ``length`` of them if given), "ints" (a list of
    integers), "curve" (a list of [time, scale] pairs), "pairs" (a list of [x, value] pairs, x
    increasing), "tables" (an array of tables: the
    section ``<section>.<name>``), "table" (a sub-table: the section ``<section>.<name>``).
    ``default``: REQUIRED, OPTIONAL (may be left out, no value) or the value. Bounds
    ``minimum``/``maximum`` apply to the number or to each element of a list; ``open_min`` /
    ``open_max`` make them strict. ``quantity``: the physical quantity whose plausible range
    (``PLAUSIBLE``) and unit slips (``UNIT_SLIPS``) apply. ``upper_of``: this key is the upper
    end of a range whose lower end is that key (a swapped range is refused)."""

    name: str
    kind: str
    description: str
    unit: str = ""
    default: object = REQUIRED
    minimum: float | None = None
    maximum: float | None = None
    open_min: bool = False
    open_max: bool = False
    choices: tuple[str, ...] = ()
    length: int | None = None
    quantity: str | None = None
    upper_of: str | None = None

    @property
    def plausible(self) -> tuple[float, float] | None:
        return PLAUSIBLE[self.quantity] if self.quantity else None

    def bounds_text(self) -> str:
        """The allowed values, as the documentation and the error messages say them."""
        if self.choices:
            return ", ".join(f'"{c}"' for c in self.choices)
        if self.kind == "bool":
            return "true, false"
        parts = []
        if self.minimum is not None:
            parts.append(f"{'>' if self.open_min else '>='} {_g(self.minimum)}")
        if self.maximum is not None:
            parts.append(f"{'<' if self.open_max else '<='} {_g(self.maximum)}")
        if self.upper_of:
            parts.append(f">= {self.upper_of}")
        text = ", ".join(parts)
        if self.kind in ("float", "floats", "curve", "pairs"):
            text = f"finite{', ' + text if text else ''}"
        if self.length:
            text = f"{self.length} values{', ' + text if text else ''}"
        if self.quantity:
            low, high = PLAUSIBLE[self.quantity]
            text += f"; plausible {low:g} .. {high:g}"
        return text


@dataclass(frozen=True)
class Section:
    """A TOML table (``[name]``) or array of tables (``[[name]]``, ``array=True``). ``NAME`` in a
    name stands for a name the user chooses (a material). ``retired``: keys of earlier versions,
    each with what replaced it (the error that refuses them says so)."""

    name: str
    description: str
    keys: tuple[Key, ...]
    array: bool = False
    required: bool = False
    retired: Mapping[str, str] = field(default_factory=dict)  # former key -> what replaced it
    by_name: dict[str, Key] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "by_name", {k.name: k for k in self.keys})
        if len(self.by_name) != len(self.keys):
            raise ValueError(f"config schema: a key of [{self.name}] is declared twice")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)

    def key(self, name: str) -> Key:
        return self.by_name[name]


def _g(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _length(name: str, description: str, default=REQUIRED) -> Key:
    return Key(name, "float", description, "mm", default, 0.0, MAX_LENGTH, open_min=True)


def _time(name: str, description: str, default=REQUIRED, positive=True) -> Key:
    return Key(name, "float", description, "s", default, 0.0, MAX_TIME, open_min=positive)


def _strength(name: str, description: str, default=REQUIRED) -> Key:
    return Key(name, "float", description, "MPa", default, 0.0, open_min=True, quantity="strength")


def _fracture_energy(
    name: str, description: str, default=REQUIRED, quantity: str = "fracture energy"
) -> Key:
    return Key(name, "float", description, "N/mm", default, 0.0, open_min=True, quantity=quantity)


def _range_pair(what: str) -> tuple[Key, Key]:
    return (
        Key("x_min", "float", f"lower end of the x range {what}", "mm", OPTIONAL),
        Key("x_max", "float", f"upper end of the x range {what}", "mm", OPTIONAL, upper_of="x_min"),
    )


_FACE_RANGE = (
    Key("x", "float", "only the face's nodes on this node line across the width", "mm", OPTIONAL),
    Key("x_min", "float", "only the face's nodes with x >= x_min (a pad)", "mm", OPTIONAL),
    Key(
        "x_max",
        "float",
        "only the face's nodes with x <= x_max (a pad)",
        "mm",
        OPTIONAL,
        upper_of="x_min",
    ),
)
_TIME_CURVE = (
    _time("rise_time", "time curve 0 -> 1 over this time, then held (or give curve)", OPTIONAL),
    Key(
        "profile",
        "choice",
        "shape of the rise: smoothstep 3s^2 - 2s^3 (zero rate at both ends) or straight",
        default="smooth",
        choices=tuple(Profile),
    ),
    Key(
        "curve",
        "curve",
        "time curve [[t0, s0], [t1, s1], ...]: piecewise linear, held after (times s, "
        f"0 .. {_g(MAX_TIME)}, not decreasing; scales dimensionless)",
        "",
        OPTIONAL,
        -1e6,
        1e6,
    ),
)

# a rigid body's contact with its face: the [impactor]'s and every [[rigid]] body's
_CONTACT = (
    Key(
        "penalty",
        "float",
        "contact stiffness per node (default: through-thickness stiffness of a node's column, "
        "capped for stability)",
        "N/mm",
        OPTIONAL,
        0.0,
        open_min=True,
    ),
    Key(
        "friction",
        "float",
        "Coulomb friction coefficient with the face (regularised stick: a tangential spring of "
        "the penalty's stiffness); its dissipation is the history column <name>_friction_energy",
        "",
        0.0,
        0.0,
        10.0,
    ),
)


def _scalar_motion(subject: str) -> tuple[Key, Key]:
    """A prescribed motion of one component: ``displacement`` (mm) or ``velocity`` (mm/s)
    times the time curve, ``subject`` naming what moves ("" for the entry's own DOFs)."""
    return (
        Key(
            "displacement",
            "float",
            f"{subject}displacement times the time curve (or velocity)",
            "mm",
            OPTIONAL,
            -MAX_DISPLACEMENT,
            MAX_DISPLACEMENT,
        ),
        Key(
            "velocity",
            "float",
            f"{subject}velocity times the time curve (or displacement)",
            "mm/s",
            OPTIONAL,
            -MAX_SPEED,
            MAX_SPEED,
        ),
    )


_FACE = Key(
    "face",
    "face",
    "face group (x0, x1, y0, y1, bottom, top, x0_layer0, ...); a&b: the nodes on both",
)

SECTIONS: tuple[Section, ...] = (
    Section(
        "model",
        "what is modelled",
        (
            Key(
                "kind",
                "choice",
                "equivalent single layer, adaptive (ESL refined towards layerwise), or layerwise",
                choices=tuple(ModelKind),
            ),
            Key(
                "thickness_integration",
                "choice",
                'through-thickness integration of the elements: "preintegrated" (the plies '
                "pre-integrated onto three points, exact in bending for any ply count; where "
                "that rule is not positive definite, and with ply_damage, points_per_ply "
                'points in each ply) or "plies" (points_per_ply Gauss points in each ply)',
                default=str(ThicknessIntegration.PREINTEGRATED),
                choices=tuple(ThicknessIntegration),
            ),
            Key(
                "points_per_ply",
                "int",
                "Gauss points through the thickness of each ply where the plies are integrated "
                "one by one (2 integrate the bending stiffness exactly; 1 warns of its error)",
                default=2,
                minimum=1,
                maximum=2,
            ),
            Key(
                "shear_correction",
                "bool",
                "the laminate's transverse shear correction factors on every element of "
                "several plies (from the exact shear distribution of the laminate; one-ply "
                "elements keep the plies' moduli; false: none)",
                default=True,
            ),
            Key(
                "enhanced_strain",
                "bool",
                "the enhanced assumed thickness strain of every element (no Poisson thickness "
                "locking in bending; false: the compatible strain alone, for comparison)",
                default=True,
            ),
            Key(
                "kinematics",
                "choice",
                "small strain, or finite (total Lagrangian, large rotations; with ply_damage the"
                " damaged cells co-rotate)",
                default="small",
                choices=tuple(Kinematics),
            ),
            Key(
                "ply_damage",
                "bool",
                "matrix damage per (cell, ply), and fibre damage where the material gives Gft "
                "and Gfc; needs [materials.NAME.failure]",
                default=False,
            ),
            Key(
                "erosion",
                "bool",
                "remove the (sub)elements whose plies' fibres have all failed from the force "
                "computation (their mass stays on their nodes); needs ply_damage and Gft, Gfc",
                default=False,
            ),
            Key(
                "erosion_volume_ratio",
                "float",
                "with erosion: also remove an element crushed below this ratio of its volume at "
                "a corner (the edges' det, deformed over reference) or, under finite "
                "kinematics, as a whole, its fibres then broken",
                default=0.2,
                minimum=0.0,
                maximum=1.0,
                open_min=True,
                open_max=True,
            ),
            Key(
                "check_units",
                "bool",
                "refuse densities, moduli, strengths, fracture energies and penalties outside "
                "their plausible range (false: accept unusual materials)",
                default=True,
            ),
            Key(
                "max_memory",
                "float",
                "largest estimated memory of the model (all ranks); raise it to run larger models",
                "GB",
                DEFAULT_MAX_MEMORY_GB,
                0.0,
                open_min=True,
            ),
        ),
        required=True,
    ),
    Section(
        "mesh",
        "the plate or beam, or the shell, and its cells",
        (
            Key(
                "kind",
                "choice",
                'the flat "plate" (or beam) of structured cells; a shell Gmsh generates '
                '("tube", "panel", "hat", "plate_with_hole"); or a quadrilateral surface from '
                'a "file"; a shell is extruded along its normal (each kind\'s keys below)',
                default=str(MeshKind.PLATE),
                choices=tuple(MeshKind),
            ),
            _length(
                "length",
                "plate, plate_with_hole: length along x; tube, panel, hat: length along the axis x",
                OPTIONAL,
            ),
            _length("width", "plate, plate_with_hole: width along y; hat: crown width", OPTIONAL),
            Key("nx", "int", "plate: cells along x", default=OPTIONAL, minimum=1),
            Key("ny", "int", "plate: cells along y", default=OPTIONAL, minimum=1),
            _length("radius", "tube, panel: radius of the surface about the x axis", OPTIONAL),
            Key(
                "angle",
                "float",
                "panel: the angle it spans about the x axis",
                "degrees",
                OPTIONAL,
                0.0,
                360.0,
                open_min=True,
                open_max=True,
            ),
            Key(
                "start",
                "float",
                "panel: where its span starts, from +z towards +y (default: -angle / 2, "
                "symmetric about the crown)",
                "degrees",
                OPTIONAL,
                -360.0,
                360.0,
            ),
            Key(
                "n_around", "int", "tube, panel: cells around the axis", default=OPTIONAL, minimum=1
            ),
            Key(
                "n_along",
                "int",
                "tube, panel, hat: cells along the axis",
                default=OPTIONAL,
                minimum=1,
            ),
            _length("height", "hat: height of the crown above the flanges", OPTIONAL),
            _length("flange", "hat: width of each flange", OPTIONAL),
            _length("hole_radius", "plate_with_hole: radius of the centred hole", OPTIONAL),
            _length(
                "size", "hat, plate_with_hole: cell size in the profile or the plate", OPTIONAL
            ),
            Key(
                "file",
                "string",
                "file: a Gmsh .msh or .geo of quadrilaterals (relative to the config file); its "
                "physical curves name the side faces",
                default=OPTIONAL,
            ),
            Key(
                "surface",
                "string",
                "file: the physical surface to take (default: every surface)",
                default=OPTIONAL,
            ),
            Key(
                "reference",
                "choice",
                "shells: the laminate surface the given surface is",
                default=str(SurfaceReference.MIDDLE),
                choices=tuple(SurfaceReference),
            ),
            Key(
                "direction",
                "floats",
                "shells: the material 1-direction before the ply angle, projected on the "
                "surface (default: global x, or z where x is normal to it, as Abaqus)",
                default=OPTIONAL,
                length=3,
            ),
            Key(
                "orientation",
                "choice",
                "tube, panel, hat: the material 1-direction along the axis or around it "
                "(instead of direction; default axial)",
                default=OPTIONAL,
                choices=tuple(MaterialAxis),
            ),
            Key(
                "normal",
                "floats",
                "file: the side the shell's normals point to (on average over each connected "
                "piece, refused where perpendicular to it; default: the first quadrilateral's)",
                default=OPTIONAL,
                length=3,
            ),
            Key(
                "layers",
                "ints",
                "layerwise only: plies per mesh layer, bottom to top (default one per ply)",
                default=OPTIONAL,
                minimum=1,
            ),
            Key(
                "partition",
                "choice",
                'on several MPI ranks, patches of equal "cost" (an adaptive model\'s cells '
                "under an insert film, refined from the start, count as several unrefined "
                'ones) or of equal "cells"',
                default=str(Partition.COST),
                choices=tuple(Partition),
            ),
            Key(
                "rebalance",
                "float",
                "on several MPI ranks, an adaptive run whose refinement makes the costliest "
                "rank's cost this many times the mean cuts its partition again, weighted by "
                "the refinement (through a checkpoint, once a refinement's ties and damping "
                "windows are over); 0: never",
                default=REBALANCE,
                minimum=0.0,
            ),
        ),
        required=True,
    ),
    Section(
        "materials.NAME",
        "a transversely isotropic ply material (E3 = E2, G13 = G12, nu13 = nu12)",
        (
            Key(
                "E1",
                "float",
                "modulus along the fibres",
                "MPa",
                minimum=0.0,
                open_min=True,
                quantity="modulus",
            ),
            Key(
                "E2",
                "float",
                "transverse modulus (= E3)",
                "MPa",
                minimum=0.0,
                open_min=True,
                quantity="modulus",
            ),
            Key(
                "G12",
                "float",
                "in-plane shear modulus (= G13)",
                "MPa",
                minimum=0.0,
                open_min=True,
                quantity="modulus",
            ),
            Key(
                "G23",
                "float",
                "transverse shear modulus (default E2 / (2 (1 + nu23)))",
                "MPa",
                OPTIONAL,
                0.0,
                open_min=True,
                quantity="modulus",
            ),
            Key(
                "nu12",
                "float",
                "Poisson's ratio (= nu13); the stiffness must be positive "
                "definite: nu12^2 < E1/E2 (1 - nu23)/2",
                "",
                REQUIRED,
                -1.0,
                open_min=True,
            ),
            Key(
                "nu23",
                "float",
                "transverse Poisson's ratio",
                "",
                REQUIRED,
                -1.0,
                1.0,
                open_min=True,
                open_max=True,
            ),
            Key(
                "rho",
                "float",
                "density",
                "tonne/mm^3",
                minimum=0.0,
                open_min=True,
                quantity="density",
            ),
            Key(
                "failure",
                "table",
                "strengths and fracture energies ([materials.NAME.failure])",
                default=OPTIONAL,
            ),
        ),
        required=True,
    ),
    Section(
        "materials.NAME.failure",
        "ply strengths (Hashin) and fracture energies, for ply_damage and indicators",
        (
            _strength("XT", "fibre tensile strength"),
            _strength("XC", "fibre compressive strength"),
            _strength("YT", "transverse tensile strength"),
            _strength("YC", "transverse compressive strength"),
            _strength("S12", "in-plane shear strength"),
            _strength(
                "S23", "transverse shear strength (default YC / (2 tan 53 deg)); > YT / 2", OPTIONAL
            ),
            _fracture_energy("G2c", "matrix mode I fracture energy"),
            _fracture_energy("G6c", "matrix in-plane shear fracture energy"),
            _fracture_energy(
                "Gft",
                "fibre tension fracture energy (with Gfc: the fibres break under ply_damage; "
                "without: fibre failure is an index only)",
                OPTIONAL,
                "fibre fracture energy",
            ),
            _fracture_energy(
                "Gfc",
                "fibre (kink-band) compression fracture energy",
                OPTIONAL,
                "fibre fracture energy",
            ),
        ),
    ),
    Section(
        "laminate",
        "the plies, bottom to top: material + ply_thickness + angles, or plies",
        (
            Key(
                "material", "string", "material of every ply (a [materials.NAME])", default=OPTIONAL
            ),
            Key(
                "ply_thickness",
                "float",
                "thickness of every ply",
                "mm",
                OPTIONAL,
                MIN_LENGTH,
                MAX_LENGTH,
            ),
            Key(
                "angles",
                "floats",
                f"ply angles, bottom to top (at most {MAX_PLIES} plies)",
                "deg",
                OPTIONAL,
                -360.0,
                360.0,
            ),
            Key(
                "plies",
                "tables",
                f"instead: one table per ply ([[laminate.plies]], at most {MAX_PLIES})",
                "",
                OPTIONAL,
            ),
        ),
        required=True,
    ),
    Section(
        "laminate.plies",
        "one ply, bottom to top",
        (
            Key("material", "string", "material (a [materials.NAME])"),
            Key("angle", "float", "fibre angle from x towards y", "deg", REQUIRED, -360.0, 360.0),
            Key("thickness", "float", "ply thickness", "mm", REQUIRED, MIN_LENGTH, MAX_LENGTH),
        ),
        array=True,
    ),
    Section(
        "clamp",
        "a face with all three displacement components held at zero",
        (_FACE, *_FACE_RANGE),
        array=True,
    ),
    Section(
        "prescribed",
        "one displacement component of a face's nodes driven in time",
        (
            _FACE,
            Key("component", "choice", "displacement component", choices=("x", "y", "z")),
            *_scalar_motion(""),
            *_FACE_RANGE,
            *_TIME_CURVE,
        ),
        array=True,
    ),
    Section(
        "load",
        "a total force spread over one face (or the part of it in a region) as a uniform"
        " traction, or a pressure normal to it, times a time curve; give force or pressure",
        (
            Key("face", "face", "face group the load acts on (one face, not an edge a&b)"),
            Key(
                "force",
                "floats",
                "[Fx, Fy, Fz], total over the face (or its region)",
                "N",
                OPTIONAL,
                -MAX_FORCE,
                MAX_FORCE,
                length=3,
            ),
            Key(
                "pressure",
                "float",
                "normal to the face; positive pushes into the body (against the outward normal)",
                "MPa",
                OPTIONAL,
                -MAX_PRESSURE,
                MAX_PRESSURE,
            ),
            Key(
                "distribution",
                "pairs",
                "the pressure's factor along x: [[x, factor], ...], x increasing, linear between"
                " the points, held at the end values outside them (default: 1)",
                "mm",
                OPTIONAL,
            ),
            Key("x_min", "float", "only the facets with centroid x >= x_min", "mm", OPTIONAL),
            Key(
                "x_max",
                "float",
                "only the facets with centroid x <= x_max",
                "mm",
                OPTIONAL,
                upper_of="x_min",
            ),
            Key("y_min", "float", "only the facets with centroid y >= y_min", "mm", OPTIONAL),
            Key(
                "y_max",
                "float",
                "only the facets with centroid y <= y_max",
                "mm",
                OPTIONAL,
                upper_of="y_min",
            ),
            *_TIME_CURVE,
        ),
        array=True,
    ),
    Section(
        "solver",
        "explicit central differences",
        (
            Key("end_time", "float", "time simulated", "s", REQUIRED, 0.0, open_min=True),
            Key(
                "safety_factor",
                "float",
                "factor on the stable time step",
                "",
                0.9,
                0.0,
                1.0,
                open_min=True,
            ),
            Key(
                "time_step",
                "float",
                "forced time step (refused above the stable one)",
                "s",
                OPTIONAL,
                0.0,
                open_min=True,
            ),
            Key(
                "mass_damping",
                "float",
                "mass-proportional damping on every free DOF",
                "1/s",
                0.0,
                0.0,
            ),
            Key(
                "mass_scaling",
                "choice",
                '"selective": the through-thickness modes get mass so that thin layers '
                "step at the in-plane step (ESL and layerwise models)",
                "",
                MassScaling.NONE,
                choices=tuple(MassScaling),
            ),
            Key(
                "mass_scaling_step",
                "float",
                "the step selective mass scaling aims at (default: the in-plane step)",
                "s",
                OPTIONAL,
                0.0,
                open_min=True,
            ),
            Key(
                "max_steps",
                "int",
                "a run (and check) refuses more time steps than this",
                "",
                DEFAULT_MAX_STEPS,
                1,
            ),
            Key(
                "energy_error_limit",
                "float",
                "the run fails when |energy balance| exceeds this "
                "share of the largest energy of the run",
                "",
                0.2,
                0.0,
                open_min=True,
            ),
        ),
        required=True,
    ),
    Section(
        "output",
        "what is written",
        (
            Key(
                "interval",
                "float",
                "time between history rows (<= solver.end_time)",
                "s",
                REQUIRED,
                0.0,
                open_min=True,
            ),
            Key(
                "fields_interval",
                "float",
                "time between field outputs (default: none)",
                "s",
                OPTIONAL,
                0.0,
                open_min=True,
            ),
            Key(
                "fields_plies",
                "ints",
                "plies (1-based) in the ply field file plies.pvd (default: all)",
                "",
                OPTIONAL,
                1,
            ),
            Key(
                "fields_box",
                "floats",
                "field files hold only the elements whose centroid lies in "
                "[x_min, x_max, y_min, y_max, z_min, z_max] (default: all)",
                "mm",
                OPTIONAL,
                length=6,
            ),
            Key(
                "ply_fields_every",
                "int",
                "the ply field file at every n-th field output only",
                "",
                1,
                1,
            ),
            Key(
                "checkpoint_interval",
                "int",
                "steps between checkpoints (default: none)",
                "",
                OPTIONAL,
                1,
            ),
            Key("displacement_face", "face", "history displacement: mean over this face"),
            Key(
                "displacement_x",
                "float",
                "only the displacement face's node line at this x",
                "mm",
                OPTIONAL,
            ),
            Key(
                "reaction_face", "face", "history reaction force on this clamped or prescribed face"
            ),
            Key(
                "component",
                "choice",
                "component of the displacement and the forces",
                choices=("x", "y", "z"),
            ),
        ),
        required=True,
    ),
    Section(
        "interfaces",
        "ply interfaces, 1-based (interface i lies between ply i and i + 1)",
        (
            Key("refine", "ints", "adaptive: may refine weakly", "", (), 1),
            Key(
                "delaminate",
                "ints",
                "adaptive: may turn strong; layerwise: cohesive elements",
                "",
                (),
                1,
            ),
            Key("symmetry", "ints", "nodes held at u_z = 0 (a symmetry plane)", "", (), 1),
            Key(
                "initial",
                "choice",
                "adaptive: refinement at t = 0",
                default="none",
                choices=tuple(Refinement),
            ),
        ),
    ),
    Section(
        "delamination",
        "an insert film: a region of an interface delaminated at t = 0 (cells whose centroid"
        " lies in it; layerwise: failed cohesive elements, adaptive: cells refined strongly there"
        " with failed cohesive elements; the crack faces still meet in the cohesive law's"
        " undamaged compression branch, frictionless)",
        (
            Key(
                "interface", "int", "the interface, one of [interfaces] delaminate", "", REQUIRED, 1
            ),
            Key("x_min", "float", "lower end of the region's x range", "mm", REQUIRED),
            Key(
                "x_max",
                "float",
                "upper end of the region's x range",
                "mm",
                REQUIRED,
                upper_of="x_min",
            ),
            Key(
                "y_min", "float", "lower end of the region's y range (default: all)", "mm", OPTIONAL
            ),
            Key(
                "y_max",
                "float",
                "upper end of the region's y range (default: all)",
                "mm",
                OPTIONAL,
                upper_of="y_min",
            ),
        ),
        array=True,
    ),
    Section(
        "refinement",
        "adaptive: a manual refinement at a time or a probe displacement",
        (
            _time("time", "refine at this time (or displacement)", OPTIONAL, positive=False),
            Key(
                "displacement",
                "float",
                "refine when |probe displacement| reaches this",
                "mm",
                OPTIONAL,
                0.0,
                MAX_DISPLACEMENT,
                open_min=True,
            ),
            Key("interfaces", "ints", "interfaces to refine", "", REQUIRED, 1),
            Key("kind", "choice", "weak or strong", choices=(Refinement.WEAK, Refinement.STRONG)),
            *_range_pair("of the refined cells' centroids"),
        ),
        array=True,
    ),
    Section(
        "cohesive",
        "bilinear mixed-mode cohesive law of the delaminating interfaces",
        (
            Key(
                "K_n",
                "float",
                "normal penalty stiffness",
                "N/mm^3",
                minimum=0.0,
                open_min=True,
                quantity="penalty",
            ),
            Key(
                "K_s",
                "float",
                "shear penalty stiffness",
                "N/mm^3",
                minimum=0.0,
                open_min=True,
                quantity="penalty",
            ),
            Key(
                "N",
                "float",
                "normal strength",
                "MPa",
                minimum=0.0,
                open_min=True,
                quantity="strength",
            ),
            Key(
                "S",
                "float",
                "shear strength",
                "MPa",
                minimum=0.0,
                open_min=True,
                quantity="strength",
            ),
            Key(
                "GIc",
                "float",
                "mode I fracture energy",
                "N/mm",
                minimum=0.0,
                open_min=True,
                quantity="fracture energy",
            ),
            Key(
                "GIIc",
                "float",
                "mode II fracture energy",
                "N/mm",
                minimum=0.0,
                open_min=True,
                quantity="fracture energy",
            ),
            Key(
                "law",
                "choice",
                "mixed-mode criterion: Benzeggagh-Kenane or power law",
                choices=tuple(MixedModeLaw),
            ),
            Key(
                "exponent",
                "float",
                "eta (bk) or alpha (power)",
                "",
                REQUIRED,
                0.0,
                20.0,
                open_min=True,
            ),
        ),
    ),
    Section(
        "matrix_strength",
        "ply_damage: matrix strength YT scaled in the cells whose centroid lies in an x range",
        (
            Key("plies", "ints", "plies, 1-based", "", REQUIRED, 1),
            Key(
                "factor",
                "float",
                "x YT: < 1 a flaw, > 1 cells kept from crushing",
                "",
                REQUIRED,
                0.0,
                10.0,
                open_min=True,
            ),
            *_range_pair("of the cells' centroids (default: all)"),
        ),
        array=True,
    ),
    Section(
        "indicators",
        "adaptive: automatic refinement",
        (
            Key(
                "interval",
                "float",
                "time between evaluations (default: a shear wave's time across the band "
                "refined ahead of a front)",
                "s",
                OPTIONAL,
                0.0,
                open_min=True,
            ),
            Key(
                "ply_failure",
                "float",
                "weak where the Hashin index reaches this",
                "",
                OPTIONAL,
                0.0,
                10.0,
                open_min=True,
            ),
            Key(
                "interface_stress",
                "float",
                "strong where the estimated interlaminar stress reaches this fraction of the "
                "cohesive initiation criterion (default 0.9 where an interface may delaminate; "
                "0: off)",
                "",
                OPTIONAL,
                0.0,
                10.0,
            ),
            Key(
                "look_ahead",
                "bool",
                "interface_stress also refines where the index predicted one lead time "
                "(interval + release_window) ahead reaches it: the index's rise over the last "
                "lead time continued",
                default=True,
            ),
            Key("matrix_damage", "bool", "strong next to a cracked ply", default=False),
            Key(
                "spread",
                "int",
                "rings of neighbours refined with a flagged cell",
                "",
                0,
                0,
                MAX_RINGS,
            ),
            _time("strong_after", "weak turns strong this long after", OPTIONAL, positive=False),
            Key(
                "front_distance",
                "float",
                "kept refined around a started delamination "
                "(default: the process zone length plus two sublaminate thicknesses; 0: none)",
                "mm",
                OPTIONAL,
                0.0,
                MAX_LENGTH,
            ),
        ),
        retired={
            "front": "rings of cells are now front_distance in mm (by default the interface's "
            "process zone length plus two sublaminate thicknesses)"
        },
    ),
    Section(
        "impactor",
        "a rigid body hitting the top face (penalty contact, Coulomb friction if asked)",
        (
            Key(
                "shape",
                "choice",
                "sphere, or cylinder with its axis along y",
                choices=(ImpactorShape.SPHERE, ImpactorShape.CYLINDER),
            ),
            _length("radius", "radius"),
            Key("mass", "float", "mass", "tonne", REQUIRED, 0.0, 1e6, open_min=True),
            Key(
                "position",
                "floats",
                "[x, y, z] of the centre",
                "mm",
                REQUIRED,
                -MAX_LENGTH,
                MAX_LENGTH,
                length=3,
            ),
            Key(
                "velocity",
                "floats",
                "[vx, vy, vz]",
                "mm/s",
                REQUIRED,
                -MAX_SPEED,
                MAX_SPEED,
                length=3,
            ),
            *_CONTACT,
        ),
    ),
    Section(
        "rigid",
        "a rigid loading body (roller, nose, support, impactor) in penalty contact with the top"
        " or bottom face, Coulomb friction if asked",
        (
            Key(
                "name",
                "string",
                "its history columns <name>_force, <name>_displacement (and with friction "
                "<name>_friction_energy)",
            ),
            Key(
                "shape",
                "choice",
                "sphere, cylinder with its axis along axis, or plane with its normal",
                choices=tuple(ImpactorShape),
            ),
            Key("axis", "choice", "a cylinder's axis", default="y", choices=("x", "y")),
            _length("radius", "sphere, cylinder: radius", OPTIONAL),
            Key(
                "normal",
                "floats",
                "plane: [nx, ny, nz], its normal, pointing from the plane to the structure "
                "(scaled to length 1)",
                "",
                OPTIONAL,
                -1e6,
                1e6,
                length=3,
            ),
            Key(
                "position",
                "floats",
                "[x, y, z] of the centre (a point of the axis; a point of the plane) at t = 0",
                "mm",
                REQUIRED,
                -MAX_LENGTH,
                MAX_LENGTH,
                length=3,
            ),
            Key(
                "face",
                "choice",
                "the face it may touch: top, bottom, or all (every node of the laminate: both "
                "faces, the layers between, the extra nodes of refined cells; a platen on the "
                "edge of a plate or the end of a tube)",
                choices=("top", "bottom", "all"),
            ),
            Key(
                "motion",
                "choice",
                "fixed (a support), prescribed (moved by displacement or velocity times the time"
                " curve), free (a mass with an initial velocity) or lever (the saddle the [lever]"
                " carries)",
                choices=tuple(RigidMotion),
            ),
            Key("mass", "float", "free: its mass", "tonne", OPTIONAL, 0.0, 1e6, open_min=True),
            Key(
                "velocity",
                "floats",
                "free: [vx, vy, vz] at t = 0; prescribed: times the time curve",
                "mm/s",
                OPTIONAL,
                -MAX_SPEED,
                MAX_SPEED,
                length=3,
            ),
            Key(
                "displacement",
                "floats",
                "prescribed: [dx, dy, dz] times the time curve",
                "mm",
                OPTIONAL,
                -MAX_DISPLACEMENT,
                MAX_DISPLACEMENT,
                length=3,
            ),
            *_TIME_CURVE,
            *_CONTACT,
        ),
        array=True,
    ),
    Section(
        "lever",
        "the loading lever of a mixed-mode bending test (ASTM D6671): rigid and massless, hinged"
        " to a node line, resting on a [[rigid]] saddle, pushed down at its load point; hinge,"
        " saddle and load point on one line in this order, the half-span L (hinge to saddle)"
        " from the geometry. History: lever_force, lever_displacement (load point), "
        "hinge_force, hinge_displacement",
        (
            Key("saddle", "string", 'the [[rigid]] body (motion = "lever") it rests on'),
            Key(
                "hinge",
                "face",
                "the node line it is hinged to (the upper arm's end, e.g. x1&top)",
            ),
            _length("load_arm", "c: from the saddle to the load point (sets the mode mixity)"),
            *_scalar_motion("the load point's z "),
            *_TIME_CURVE,
        ),
    ),
    Section(
        "stabilisation",
        "adaptive: damping after a weak refinement, tie force released after a strong one",
        (
            Key("damping", "float", "mass damping after a weak refinement", "1/s", 0.0, 0.0),
            Key("damping_window", "float", "how long the damping acts", "s", 0.0, 0.0, MAX_TIME),
            Key(
                "release_window",
                "float",
                "tie force of a strong refinement released over (and let go where its pair "
                "moves on: past the opening its cohesive element carries it at)",
                "s",
                0.0,
                0.0,
                MAX_TIME,
            ),
            Key(
                "equilibrate",
                "bool",
                "the refined cells' nodes start in balance, each with the acceleration it had, "
                "the other nodes held (a linear solve per refinement; false: where the split "
                "element's field puts them); "
                "left out: on without ply damage, off with it (the elastic tangent is not a "
                "damaged ply's)",
                default=OPTIONAL,
            ),
        ),
    ),
)

_BY_NAME = {s.name: s for s in SECTIONS}
TOP_LEVEL = (*(s.name for s in SECTIONS if "." not in s.name), "materials")


def section(name: str) -> Section:
    """The section called ``name`` (e.g. "mesh", "materials.NAME", "laminate.plies")."""
    return _BY_NAME[name]


def all_keys() -> set[str]:
    """Every key as "section.key" (e.g. "materials.NAME.rho", "clamp.face")."""
    return {f"{s.name}.{k.name}" for s in SECTIONS for k in s.keys}


def implausible(key: Key, value: float) -> str | None:
    """The complaint about a value outside its quantity's plausible range, with the value the
    likely unit slip would give; None if it is plausible (or has no plausible range).

    Parameters:
        key: the schema key (its ``quantity`` and ``unit``).
        value: the value as given, in the key's unit.
    """
    if key.quantity is None:
        return None
    low, high = PLAUSIBLE[key.quantity]
    if low <= value <= high:
        return None
    text = (
        f"{value:g} {key.unit} is implausible for a solid (expected {low:g} .. {high:g})"
        if key.quantity != "penalty"
        else f"{value:g} {key.unit} is an implausible penalty stiffness (expected {low:g} .. "
        f"{high:g})"
    )
    for given, unit, factor in UNIT_SLIPS[key.quantity]:
        if low <= value * factor <= high:
            text += f"; did you mean {value * factor:.6g} ({given} -> {unit})?"
            break
    return text + " (model.check_units = false accepts unusual values)"


def _default_text(key: Key) -> str:
    if key.default is REQUIRED:
        return "required"
    if key.default is OPTIONAL:
        return "-"
    if isinstance(key.default, bool):
        return "true" if key.default else "false"
    if isinstance(key.default, str):
        return f'"{key.default}"'
    if isinstance(key.default, tuple):
        return "[]"
    if isinstance(key.default, int) and key.default >= 10**6:
        return f"{key.default:.0e}".replace("e+0", "e").replace("e+", "e")
    return _g(key.default)


def _type_text(key: Key) -> str:
    return {
        "float": "number",
        "int": "integer",
        "bool": "boolean",
        "choice": "string",
        "string": "string",
        "face": "face",
        "floats": "list of numbers",
        "ints": "list of integers",
        "curve": "list of [t, s]",
        "pairs": "list of [x, value]",
        "tables": "array of tables",
        "table": "table",
    }[key.kind]


def reference_markdown() -> str:
    """The config reference as Markdown: a short introduction, then one table per section
    (key, type, unit, default, allowed values, description)."""
    lines = [
        "# Config reference",
        "",
        "Units: N, mm, s, tonne (stress and moduli MPa, density tonne/mm^3, energy mJ, fracture "
        "energy N/mm). Every number must be finite. Unknown keys are errors. A bad value stops "
        "the program before anything runs, with one line naming the key (exit status 2).",
        "",
        f"Limits: at most {MAX_PLIES} plies; lengths up to {_g(MAX_LENGTH)} mm; cells and plies "
        f"at least {_g(MIN_LENGTH)} mm thick; a cell's longest side at most {_g(MAX_ASPECT)} x "
        "its shortest (plies alike); "
        f"forces up to {_g(MAX_FORCE)} N, speeds up to {_g(MAX_SPEED)} mm/s; the estimated "
        "memory of the model up to `model.max_memory`; the number of time steps up to "
        "`solver.max_steps`.",
        "",
        "Unit plausibility (`model.check_units = true`, the default): "
        + "; ".join(
            f"{quantity} {low:g} .. {high:g}" for quantity, (low, high) in PLAUSIBLE.items()
        )
        + " (density tonne/mm^3, moduli and strengths MPa, fracture energy N/mm, penalty "
        "N/mm^3). A value outside is refused with the value of the likely unit slip ("
        + ", ".join(
            dict.fromkeys(
                f"{given} -> {unit}" for slips in UNIT_SLIPS.values() for given, unit, _ in slips
            )
        )
        + "); `check_units = false` accepts unusual materials.",
        "",
    ]
    for s in SECTIONS:
        title = f"[[{s.name}]]" if s.array else f"[{s.name}]"
        need = " (required)" if s.required else ""
        lines += [f"## `{title}`{need}", "", s.description[0].upper() + s.description[1:] + ".", ""]
        lines += [
            "| key | type | unit | default | allowed | description |",
            "|---|---|---|---|---|---|",
        ]
        for k in s.keys:
            cells = (
                f"`{k.name}`",
                _type_text(k),
                k.unit or "-",
                _default_text(k),
                k.bounds_text() or "-",
                k.description.replace("|", "\\|"),
            )
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":  # python -m fenics_adaptive.settings.schema > reference.md
    print(reference_markdown())
