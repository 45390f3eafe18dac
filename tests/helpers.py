"""Helpers that several test files share: models and materials, single-cell references, TOML
text, the figures of the AFEM tutorials. Fixtures stay in ``conftest.py``; tests import these
with ``from helpers import ...`` (``tests/`` is on ``pythonpath`` in pyproject.toml).

Units: N, mm, s, tonne.
"""

from __future__ import annotations

from mpi4py import MPI  # first: the DOLFINx wheel finds libmpi through it

# isort: split
import importlib.util
import json
import math
import tomllib
from pathlib import Path

import basix.ufl
import dolfinx
import numpy as np
import pytest
import ufl
from dolfinx import fem
from fenics_adaptive.meshes import esl_mesh

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element import subelement as se
from fenics_adaptive.element.assumed_strain import cells_with_bent_directors
from fenics_adaptive.materials.laminate import Laminate, Ply, PlyMaterial
from fenics_adaptive.model.forms import CondensedThicknessStrain, LayeredModel, build_model

DATA = Path(__file__).parent / "data"  # the test configs

# ------------------------------------------------------------------ materials and models
CROSS_PLY = [0, 90, 0, 90, 90, 0, 90, 0]  # ply angles (degrees), bottom to top


# The paper's TCB ply (Table 1 as corrected in the issue) as a config's [materials.NAME] table
# (MPa, tonne/mm^3). Tests copy it (dict(PROTOTYPE_PLY)) before changing it.
PROTOTYPE_PLY = {
    "E1": 1.0e5,
    "E2": 1.0e4,
    "G12": 5.0e3,
    "G23": 4.0e3,
    "nu12": 0.25,
    "nu23": 0.25,
    "rho": 1.6e-9,
}


def prototype_material(name: str = "prototype", rho: float = 1.6e-9) -> PlyMaterial:
    """The paper's TCB ply (``PROTOTYPE_PLY``) as a PlyMaterial, of density ``rho``."""
    return PlyMaterial(name, **(PROTOTYPE_PLY | {"rho": rho}))


def esl_model(
    angles, length: float, width: float, nx: int, ny: int, ply_thickness: float = 0.25, **kw
) -> LayeredModel:
    """An ESL beam or plate (one cell through the thickness) of the prototype ply at ``angles``
    (degrees), ``length`` x ``width`` mm in ``nx`` x ``ny`` cells; ``kw`` go to ``build_model``."""
    laminate = Laminate.from_angles(prototype_material(), angles, ply_thickness)
    beam = esl_mesh(MPI.COMM_WORLD, length, width, nx, ny, laminate.thickness)
    return build_model(beam, [laminate], **kw)


# A bilinear B-K cohesive law as a config's [cohesive] table (N/mm^3, MPa, N/mm): damage starts
# at openings of N / K_n = 2e-4 mm. Tests copy it (dict(COHESIVE_LAW)) before changing it.
COHESIVE_LAW = {
    "K_n": 1.0e5,
    "K_s": 1.0e5,
    "N": 20.0,
    "S": 40.0,
    "GIc": 0.4,
    "GIIc": 1.0,
    "law": "bk",
    "exponent": 2.0,
}


# ------------------------------------------------------------------ single (sub)elements
CARBON = PlyMaterial("carbon", E1=140e3, E2=10e3, G12=5e3, nu12=0.3, nu23=0.45, rho=1.6e-9)
GLASS = PlyMaterial(
    "glass", E1=45e3, E2=12e3, G12=4.5e3, nu12=0.28, nu23=0.4, rho=2.0e-9, G23=3.5e3
)
BOX = np.array([2.0, 1.5, 1.0])  # mm; the laminate thickness is along z


def random_laminate(rng: np.random.Generator, n_plies: int) -> Laminate:
    """Unequal thicknesses, two materials, random angles (one 90-degree ply, whose stiffness has
    no xz-yz coupling, so that both forms of the cross term are exercised)."""
    thickness = rng.uniform(0.1, 0.4, n_plies)
    angles = rng.uniform(-90.0, 90.0, n_plies)
    angles[1] = 90.0
    materials = [CARBON if k % 2 == 0 else GLASS for k in range(n_plies)]
    materials[-1] = GLASS if materials[-2] is CARBON else CARBON
    return Laminate(
        tuple(
            Ply(m, float(a), float(t)) for m, a, t in zip(materials, angles, thickness, strict=True)
        )
    )


def jacobian_determinants(X: np.ndarray, n: int = 3) -> np.ndarray:
    """det(dx/dX) of the trilinear map on an n x n x n grid of [0, 1]^3 (corners included)."""
    s = np.linspace(0.0, 1.0, n)
    dets = []
    for a in s:
        for b in s:
            for c in s:
                p = np.array([a, b, c])
                factors = np.where(se.CORNERS == 1.0, p, 1.0 - p)
                slopes = np.where(se.CORNERS == 1.0, 1.0, -1.0)
                dN = np.stack(
                    [
                        slopes[:, 0] * factors[:, 1] * factors[:, 2],
                        factors[:, 0] * slopes[:, 1] * factors[:, 2],
                        factors[:, 0] * factors[:, 1] * slopes[:, 2],
                    ],
                    axis=1,
                )
                dets.append(np.linalg.det(X.T @ dN))
    return np.array(dets)


def distorted_hex(rng: np.random.Generator, size: np.ndarray = BOX, amount: float = 0.15):
    """Vertices (8, 3) of a box of ``size`` with every coordinate perturbed by up to
    ``amount`` times the edge length along it (vertices 4-7 stay roughly above 0-3)."""
    X = se.CORNERS * size + rng.uniform(-amount, amount, (8, 3)) * size
    assert jacobian_determinants(X).min() > 0.2 * np.prod(size)
    return X


def subelement_vertices(X_parent: np.ndarray, fractions: np.ndarray, first: int, stop: int):
    """Vertices (8, 3) of the subelement holding plies first:stop of a parent element: on the
    parent's vertical edges at the thickness fractions of its bounding interfaces."""
    bottom, top = X_parent[:4], X_parent[4:]
    f = fractions
    return np.vstack(
        [(1 - f[first]) * bottom + f[first] * top, (1 - f[stop]) * bottom + f[stop] * top]
    )


def laminate_rule(laminate: Laminate, ppp: int) -> se.PackedRule:
    """The kernel's packed rule of ``laminate`` with ``ppp`` points per ply."""
    return se.pack_rule(laminate.ply_fractions, np.array(laminate.ply_stiffnesses()), ppp)


def energy_gradient(energy, u: np.ndarray, h: float) -> np.ndarray:
    """Central differences, step ``h`` (mm), of the scalar ``energy(u)`` (mJ) with respect to
    each entry of the displacements ``u`` (n, 3): (n, 3) N."""
    grad = np.zeros_like(u)
    for index in np.ndindex(u.shape):
        up, down = u.copy(), u.copy()
        up[index] += h
        down[index] -= h
        grad[index] = (energy(up) - energy(down)) / (2 * h)
    return grad


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest entry of |a - b| over the largest entry of |b|."""
    return float(np.abs(a - b).max() / np.abs(b).max())


class SingleCell:
    """One hexahedron with vertices X (our order) as a DOLFINx mesh with a P1 vector space."""

    def __init__(self, X: np.ndarray):
        element = basix.ufl.element("Lagrange", "hexahedron", 1, shape=(3,))
        cells = np.arange(8, dtype=np.int64).reshape(1, 8)
        self.mesh = dolfinx.mesh.create_mesh(MPI.COMM_SELF, cells, element, X)
        nodes = self.mesh.geometry.dofmaps[0][0]
        # cell-local node k of DOLFINx is our vertex order[k]; the kernel's reference map (zeta
        # through the thickness) is the same as DOLFINx's only if that is the identity
        order = np.asarray(self.mesh.geometry.input_global_indices)[nodes]
        assert np.array_equal(order, np.arange(8)), order
        assert np.array_equal(self.mesh.geometry.x[nodes], X)
        self.V = fem.functionspace(self.mesh, ("Lagrange", 1, (3,)))
        assert self.V.dofmap.index_map_bs == 3
        self.dofs = self.V.dofmap.cell_dofs(0)  # node of local vertex k, block size 3
        self.u = fem.Function(self.V)
        self.v = ufl.TestFunction(self.V)
        # the edge-sampled thickness strain where the directors bend, as the models mark it
        self.bent = None
        if cells_with_bent_directors(X[None])[0]:
            self.bent = fem.Function(fem.functionspace(self.mesh, ("DG", 0)))
            self.bent.x.array[:] = 1.0

    def set_displacement(self, U: np.ndarray) -> None:
        self.u.x.array.reshape(-1, 3)[self.dofs] = U

    def assemble(self, form: ufl.Form) -> np.ndarray:
        """(8, 3) nodal values of a linear form in v, in our vertex order."""
        vector = fem.assemble_vector(fem.form(form))
        return vector.array.reshape(-1, 3)[self.dofs].copy()

    def force(self, laminate: Laminate, ppp: int, U: np.ndarray):
        self.set_displacement(U)
        groups = solid_shell.ply_groups(laminate, ppp)
        return self.assemble(
            solid_shell.internal_force_form(self.u, self.v, groups, bent=self.bent)
        )

    def lumped_mass(self, laminate: Laminate) -> np.ndarray:
        groups = solid_shell.ply_groups(laminate, 1)
        return self.assemble(solid_shell.lumped_mass_form(self.v, groups))[:, 0]


class EnhancedCell:
    """One hexahedron's UFL energy with the enhanced field, condensed by the model's own
    ``CondensedThicknessStrain``; ``preintegrate``: the through-thickness rule
    ``solid_shell.thickness_rule`` takes with it (else ``ppp`` points per ply)."""

    def __init__(
        self, X: np.ndarray, laminate, ppp: int, kinematics: str, preintegrate: bool = False
    ):
        self.cell = SingleCell(X)
        A = fem.functionspace(self.cell.mesh, ("DG", 1))
        self.field = fem.Function(A)
        groups = solid_shell.energy_groups(laminate, ppp, preintegrate=preintegrate)
        self.energy = solid_shell.strain_energy_form(
            self.cell.u, groups, kinematics=kinematics, enhanced=self.field, bent=self.cell.bent
        )
        self.condensed = CondensedThicknessStrain(
            self.energy, self.field, self.cell.u, self.cell.V, np.array([0]), bent=self.cell.bent
        )

    def force(self, U: np.ndarray) -> tuple[np.ndarray, float]:
        self.cell.set_displacement(U)
        self.condensed.condense()
        force = self.cell.assemble(ufl.derivative(self.energy, self.cell.u, self.cell.v))
        return force, fem.assemble_scalar(fem.form(self.energy))

    def parameter_residual(self) -> np.ndarray:
        """T^T d(energy)/d(field): the four parameters' residual at the current field."""
        A = self.field.function_space
        form = fem.form(ufl.derivative(self.energy, self.field, ufl.TestFunction(A)))
        residual = fem.assemble_vector(form).array
        return residual[self.condensed.cell_dofs[0]] @ self.condensed.T


def tip_loaded_cantilever_error(
    material: PlyMaterial, angles, slenderness: float, model: dict
) -> tuple[float, object]:
    """(ESL tip deflection / laminate beam theory with the exact shear compliance - 1, config)
    of a static cantilever of 0.25 mm plies of ``material`` at ``angles`` (degrees), span
    ``slenderness`` times its thickness in 0.25 mm cells, 1 mm wide, clamped at x = 0, 1 N
    down on its top face; ``model``: the [model] keys besides ``kind = "esl"``."""
    from fenics_adaptive.analysis import comparison as cmp
    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import build_structure

    thickness = 0.25 * len(angles)
    length = slenderness * thickness
    fields = ("E1", "E2", "G12", "nu12", "nu23", "rho", "G23")
    ply = {k: getattr(material, k) for k in fields if getattr(material, k) is not None}
    data = {
        "model": {"kind": "esl", **model},
        "mesh": {"length": length, "width": 1.0, "nx": round(length / 0.25), "ny": 2},
        "materials": {"ply": ply},
        "laminate": {"material": "ply", "ply_thickness": 0.25, "angles": list(angles)},
        "clamp": [{"face": "x0"}],
        "load": [{"face": "top", "force": [0.0, 0.0, -1.0], "curve": [[0.0, 1.0]]}],
        "solver": {"end_time": 1e-6},
        "output": {"interval": 1e-6, "displacement_face": "x1", "reaction_face": "x0",
                   "component": "z"},
    }  # fmt: skip
    config = parse_config(data)
    structure = build_structure(config)
    cmp.solve_linear_static(structure)
    theory = cmp.CantileverBeamTheory(config.laminate, length, 1.0, 1.0)
    return cmp.tip_deflection(structure) / theory.tip_deflection()["total_mm"] - 1.0, config


# ------------------------------------------------------------------ explicit dynamics
def highest_frequency(model, fixed: np.ndarray, iterations: int = 400, scaled_mass=None) -> float:
    """omega_max (1/s): omega_max^2 = largest eigenvalue of M^-1 K on the free DOFs by power
    iteration (K u = f_int(u)), M the lumped masses, or ``scaled_mass`` (a
    ``mass_scaling.SelectiveMass`` of a structure on ``model``, whose prescribed DOFs are
    ``fixed``)."""
    n = model.n_owned_dofs
    rng = np.random.default_rng(0)
    x = rng.standard_normal(len(model.u.x.array))
    f = fem.Function(model.V).x
    m = model.mass[:n]
    Mx = np.empty(n)
    lam = 0.0
    for _ in range(iterations):
        x[fixed] = 0.0
        if scaled_mass is None:
            x /= np.sqrt(np.dot(m * x[:n], x[:n]))
        else:
            x /= np.sqrt(np.dot(scaled_mass.multiply(x[:n], Mx), x[:n]))
        model.u.x.array[:] = x
        model.u.x.scatter_forward()
        model.internal_force(f)
        if scaled_mass is None:
            y = f.array[:n] / m
            y[fixed] = 0.0
            lam = np.dot(m * x[:n], y)  # Rayleigh quotient with the M-inner product
        else:
            y = f.array[:n].copy()
            scaled_mass.solve(y, np.zeros(len(fixed)))  # M_s^-1 K x, 0 on the held DOFs
            lam = np.dot(x[:n], f.array[:n])  # x.K.x with x.M_s.x = 1
        x[:n] = y
    model.u.x.array[:] = 0.0
    return math.sqrt(lam)


def crossing_times(t, y) -> np.ndarray:
    """Times where y crosses zero going upwards (linear interpolation)."""
    t, y = np.asarray(t), np.asarray(y)
    i = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


def cantilever_first_period(laminate: Laminate, width: float, length: float) -> float:
    """s: Euler-Bernoulli cantilever, omega_1 = 1.8751^2 sqrt(EI / (rho A L^4)) (mm, N)."""
    EI = laminate.narrow_beam_bending_stiffness(width)
    rho_A = laminate.areal_mass() * width
    return 2 * math.pi / (1.8751**2 * math.sqrt(EI / (rho_A * length**4)))


# ------------------------------------------------------------------ configs
def edited(path: Path, edits: tuple[tuple[str, str], ...]) -> str:
    """The text of a test config with each (old, new) replaced (each old must be there)."""
    text = path.read_text()
    for old, new in edits:
        assert old in text, (path.name, old)
        text = text.replace(old, new)
    return text


def thin_tcb_layerwise(scaling: str = "selective", end_time: float = 2.0e-4, **solver) -> dict:
    """The short TCB of ``data/tcb_layerwise.toml`` with plies of 0.064 mm (a laminate
    0.512 mm thick under 0.5 mm cells), one mesh layer per ply, at its stable step (not the
    file's forced one), with ``[solver] mass_scaling = scaling`` and ``solver`` keys."""
    text = edited(
        DATA / "tcb_layerwise.toml",
        (
            ("time_step = 4.0e-8", ""),
            ("layers = [2, 2, 2, 2]", "layers = [1, 1, 1, 1, 1, 1, 1, 1]"),
            ("ply_thickness = 0.256", "ply_thickness = 0.064"),
        ),
    )
    data = tomllib.loads(text)
    data["solver"].update(end_time=end_time, mass_scaling=scaling, **solver)
    data["output"].pop("fields_interval", None)
    return data


def thin_pulled_beam(scaling: str = "selective", displacement: float = 0.05) -> dict:
    """``data/small_beam.toml`` with plies of 0.02 mm (0.16 mm under 2.5 x 1 mm cells), its
    tip's top edge alone pulled up by ``displacement`` (mm; the nodes below move freely), with
    ``[solver] mass_scaling = scaling``, no field output."""
    text = edited(
        DATA / "small_beam.toml",
        (
            ("ply_thickness = 0.25", "ply_thickness = 0.02"),
            ('[[prescribed]]\nface = "x1"', '[[prescribed]]\nface = "x1&top"'),
            ('reaction_face = "x1"', 'reaction_face = "x1&top"'),
            ("displacement = 0.05", f"displacement = {displacement!r}"),
        ),
    )
    data = tomllib.loads(text)
    data["solver"]["mass_scaling"] = scaling
    data["output"].pop("fields_interval")
    return data


def toml_text(data: dict) -> str:
    """A TOML writer for these configs: tables (nested), arrays of tables, flat values."""
    lines = []

    def value(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    def table(name: str, entries: dict) -> None:
        lines.append(f"[{name}]")
        lines.extend(f"{k} = {value(v)}" for k, v in entries.items() if not isinstance(v, dict))
        for sub, nested in entries.items():
            if isinstance(nested, dict):
                table(f"{name}.{sub}", nested)

    for name, entries in data.items():
        if isinstance(entries, list):
            for entry in entries:
                lines.append(f"[[{name}]]")
                lines.extend(f"{k} = {value(v)}" for k, v in entry.items())
        else:
            table(name, entries)
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ documentation
# The figures each script draws (docs/afem/README.md lists them).
FIGURES = {
    "01_extra_nodes": ["01_strip_side_view"],
    "02_figure2_maps": ["02_figure2_subelements", "02_projection_matrices"],
    "03_cell_force": ["03_cell_force_arrows"],
    "04_weak_to_strong": ["04_column_fields_and_force_split"],
    "05_stabilisation": ["05_force_jump_and_remedies"],
    "06_border": ["06_border_constraint"],
}


def tube_config(kind: str = "esl", **mesh) -> dict:
    """A [0/90]s tube of the prototype ply (R 20 mm, 30 mm long, 12 x 4 cells) clamped at x0
    and pushed 0.02 mm along its axis at x1, as a config table; ``mesh`` keys replace the
    [mesh] table's."""
    data = {
        "model": {"kind": kind},
        "mesh": {"kind": "tube", "radius": 20.0, "length": 30.0, "n_around": 12, "n_along": 4},
        "materials": {"cfrp": dict(PROTOTYPE_PLY)},
        "laminate": {"material": "cfrp", "ply_thickness": 0.25, "angles": [0, 90, 90, 0]},
        "clamp": [{"face": "x0"}],
        "prescribed": [
            {"face": "x1", "component": "x", "displacement": -0.02, "rise_time": 5.0e-5}
        ],
        "solver": {"end_time": 6.0e-5},
        "output": {
            "interval": 1.0e-5,
            "displacement_face": "x1",
            "reaction_face": "x0",
            "component": "x",
        },
    }
    data["mesh"].update(mesh)
    return data


def with_cohesive_interface(data: dict, initial: str | None) -> dict:
    """``data`` (a ``tube_config``) with interface 2 delaminable, refined from the start as
    ``initial`` says (None: as the model is), and its cohesive law."""
    data["interfaces"] = {"delaminate": [2]}
    if initial:
        data["interfaces"]["initial"] = initial
    data["cohesive"] = {"K_n": 1.0e5, "K_s": 1.0e5, "N": 20.0, "S": 40.0, "GIc": 0.4,
                        "GIIc": 1.0, "law": "bk", "exponent": 2.0}  # fmt: skip
    return data


def im7_tube(end_time: float = 1.0e-4) -> dict:
    """A small adaptive [0/90]2s IM7 tube (R 10 mm, 30 mm long, 16 x 12 cells) clamped at x0,
    interfaces 2 and 6 delaminable, the indicators at their defaults, struck at its x1 end by
    a plate tilted 10 degrees (a plane on every node, driven at 5 m/s): the indicators refine
    the rim under it, and each refinement moves contact springs between the nodes of the
    columns it splits."""
    return {
        "model": {"kind": "adaptive"},
        "mesh": {"kind": "tube", "radius": 10.0, "length": 30.0, "n_around": 16, "n_along": 12},
        "materials": {"im7": {"E1": 171420.0, "E2": 9080.0, "G12": 5290.0, "nu12": 0.32,
                              "nu23": 0.5, "rho": 1.59e-9}},
        "laminate": {"material": "im7", "ply_thickness": 0.25,
                     "angles": [0, 90, 0, 90, 90, 0, 90, 0]},
        "interfaces": {"delaminate": [2, 6]},
        "cohesive": {"K_n": 1.0e5, "K_s": 1.0e5, "N": 30.0, "S": 45.0, "GIc": 0.28,
                     "GIIc": 0.79, "law": "bk", "exponent": 2.1},
        "indicators": {},
        "clamp": [{"face": "x0"}],
        "rigid": [{"name": "plate", "shape": "plane", "normal": [-1.0, 0.0, -0.17633],
                   "position": [30.01, 0.0, 11.0], "face": "all", "motion": "prescribed",
                   "velocity": [-5000.0, 0.0, 0.0], "rise_time": 2.0e-5, "profile": "smooth"}],
        "solver": {"end_time": end_time},
        "output": {"interval": 5.0e-6, "displacement_face": "x1", "reaction_face": "x0",
                   "component": "x"},
    }  # fmt: skip


def run_quietly(data: dict, out: Path, restart: Path | None = None) -> dict:
    """Run a config table into the folder ``out`` (from the checkpoint ``restart`` if given),
    without progress or log lines; returns the summary."""
    from fenics_adaptive.runner import run_config
    from fenics_adaptive.settings.config import parse_config

    return run_config(parse_config(data), out, show_progress=False, log=None, restart=restart)


def assert_restarted_history(out: Path, whole: Path, atol: float = 1e-14) -> None:
    """The history in folder ``out`` is the one in ``whole`` row for row, to round-off (rtol
    1e-12, ``atol``): no row lost, none twice, the same columns."""
    from fenics_adaptive.io.output import read_history

    resumed = read_history(out / "history.csv")
    expected = read_history(whole / "history.csv")
    assert list(resumed) == list(expected)
    assert len(resumed["time"]) == len(expected["time"])
    assert np.all(np.diff(resumed["time"]) > 0)
    for name, values in expected.items():
        np.testing.assert_allclose(resumed[name], values, rtol=1e-12, atol=atol, err_msg=name)


def theory_history(load: str, a0: float, cracks, force, compliance, width: float,
                   Gc: float) -> dict:  # fmt: skip
    """The history columns of a bending fracture test (ENF, MMB) made from its own theory: the
    elastic line of the crack a0 (mm) up to the first propagation force, then the branch, the
    crack ``cracks`` (mm) carrying the loads ``force`` (N) with the compliances
    ``compliance`` (mm/N); ``<load>_force`` and ``<load>_displacement`` (down: negative),
    dissipation ``Gc`` (N/mm) per grown area (``width`` mm), no kinetic energy, the work put in
    positive and rising."""
    elastic = np.linspace(0.0, 1.0, 50)[1:]
    initiation = force[0] * elastic
    history = {
        f"{load}_displacement": -np.concatenate([compliance[0] * initiation, compliance * force]),
        f"{load}_force": np.concatenate([initiation, force]),
        "crack_growth_area": np.concatenate([0.0 * elastic, (cracks - a0) * width]),
        "kinetic_energy": np.zeros(len(elastic) + len(cracks)),
    }
    history["cohesive_dissipation"] = Gc * history["crack_growth_area"]
    history["impact_work"] = np.cumsum(np.abs(history[f"{load}_force"]))
    return history


def quick_fracture_run(data: dict, out: Path) -> tuple[object, dict, np.ndarray, np.ndarray]:
    """Run the layerwise model of a fracture config table quietly into ``out``: (config,
    history columns as arrays, energy (mJ) each grown cohesive element dissipated, its area
    (mm^2)); grown: failed and not of an insert film."""
    from fenics_adaptive.analysis.studies import fracture_variant
    from fenics_adaptive.io.output import read_history
    from fenics_adaptive.materials.cohesive import H_DISSIPATED
    from fenics_adaptive.model.diagnostics import quad_areas
    from fenics_adaptive.runner import execute
    from fenics_adaptive.settings.config import parse_config

    config = parse_config(fracture_variant(data, "layerwise"))
    _, structure = execute(config, out, show_progress=False, log=None)
    history = {k: np.asarray(v) for k, v in read_history(out / "history.csv").items()}
    cohesive = structure.cohesive
    grown = cohesive.failed() & ~cohesive.inserted()
    dissipated = cohesive.history[cohesive.damage_row, :, H_DISSIPATED].sum(axis=1)
    areas = quad_areas(structure.gather(cohesive.nodes[:, :4], "X"))
    return config, history, dissipated[grown], areas[grown]


def assert_on_the_propagation_branch(comparison: dict, history: dict) -> None:
    """What a quick fracture run (``quick_fracture_run``) must show on its propagation branch
    against ``comparison`` (``lefm.enf_comparison`` / ``mmb_comparison``): stable growth, the
    peak within 5 % of the initiation load, the branch's force within 3 % on average and 5 %
    per bin, the kinetic energy under 1 % of the work while the crack grows, the energy
    balance within 1e-6 of the work."""
    c = comparison
    assert c["stable_growth"]
    assert c["peak_over_initiation"] == pytest.approx(1.0, abs=0.05)
    assert c["force_over_theory_mean"] == pytest.approx(1.0, abs=0.03)
    assert c["force_over_theory_bins"]
    for ratio in c["force_over_theory_bins"].values():
        assert ratio == pytest.approx(1.0, abs=0.05)
    growing = history["crack_growth_area"] > 0.0
    assert np.all(history["kinetic_energy"][growing] < 0.01 * history["impact_work"][growing])
    assert np.abs(history["energy_balance"]).max() < 1e-6 * history["impact_work"].max()


def load_benchmark(name: str):
    """The module ``benchmarks/<name>.py``, loaded from its file (``benchmarks/`` is not a
    package)."""
    path = Path(__file__).parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_same_history(serial: dict, parallel: dict, rtol: float = 1e-10) -> None:
    """Every column equal to ``rtol`` of its scale: the column's largest magnitude, and for the
    energies (mJ) the largest of any energy in the run (a balance or a dissipated energy is a
    difference of larger terms, whose round-off it carries)."""
    from fenics_adaptive.io.output import COLUMN_UNITS, body_unit

    assert serial.keys() == parallel.keys()
    assert len(serial["time"]) == len(parallel["time"]) > 10
    energies = [name for name in serial if COLUMN_UNITS.get(name, body_unit(name)) == "mJ"]
    energy_scale = max(np.abs(serial[name]).max() for name in energies)
    assert energy_scale > 0
    for name in serial:
        a, b = np.array(serial[name]), np.array(parallel[name])
        scale = energy_scale if name in energies else np.abs(a).max()
        assert np.abs(a - b).max() <= rtol * scale, name


def late_refinement_toml(
    end_time: float,
    checkpoint_interval: int | None = None,
    history_interval: float | None = 2.0e-7,
) -> str:
    """The TCB beam (tests/data/tcb_adaptive.toml, 20 cells) refined weakly at three
    interfaces at 2e-5 s and strongly at two at 4e-5 s over x >= 5 mm, with a damping window
    and a tie-force release that are both open at 6e-5 s; to ``end_time`` (s), a checkpoint
    every ``checkpoint_interval`` steps, a history row every ``history_interval`` s (None: the
    file's 2e-6 s)."""
    edits = [
        ('initial = "strong"', 'initial = "none"'),
        ("end_time = 2.0e-4", f"end_time = {end_time!r}"),
        ("fields_interval = 5.0e-5", ""),
    ]
    if history_interval is not None:
        edits.append(("interval = 2.0e-6", f"interval = {history_interval!r}"))
    text = edited(DATA / "tcb_adaptive.toml", tuple(edits))
    if checkpoint_interval is not None:
        text = text.replace("[output]", f"[output]\ncheckpoint_interval = {checkpoint_interval}")
    return (
        text
        + """
[[refinement]]
interfaces = [2, 4, 6]
kind = "weak"
time = 2.0e-5
x_min = 5.0

[[refinement]]
interfaces = [2, 6]
kind = "strong"
time = 4.0e-5
x_min = 5.0

[stabilisation]
damping = 5.0e4
damping_window = 5.0e-5
release_window = 3.0e-5
"""
    )
