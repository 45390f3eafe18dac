"""Finite rotations: total Lagrangian kinematics (Green-Lagrange strain, second Piola-Kirchhoff
stress) in the UFL element and the numba subelement kernel, and an objective cohesive element.

Units: N, mm, s, tonne (MPa, mJ).

- the numba kernel equals the UFL form to round-off under large displacements;
- a rigid 90-degree rotation of a plate strip with unrefined, weakly and strongly refined cells
  gives no internal force and no cohesive traction, and any state turned rigidly gives the same
  forces turned (objectivity);
- a slender cantilever under a large tip load (tip rotation about 45 degrees) matches the
  elastica, and its weakly refined version carries the same forces through the numba path.
"""

from __future__ import annotations

from mpi4py import MPI  # noqa: F401  (first: the DOLFINx wheel finds libmpi through it)

# isort: split
import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from helpers import (
    BOX,
    SingleCell,
    distorted_hex,
    laminate_rule,
    random_laminate,
    relative_difference,
    subelement_vertices,
)
from petsc4py import PETSc

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element import solid_shell
from fenics_adaptive.element import subelement as se
from fenics_adaptive.errors import InputError
from fenics_adaptive.materials.laminate import Laminate
from fenics_adaptive.model.assembly import add_cohesive_forces
from fenics_adaptive.model.forms import JIT_OPTIONS
from fenics_adaptive.model.loading import face_dofs
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.config import RunConfig, parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

DATA = Path(__file__).parent / "data"
ROUND_OFF = 1e-12


def finite_structure(name: str, **model) -> tuple[RunConfig, Structure]:
    """Config and structure of a test config that asks for kinematics = "finite"; ``model``:
    keys of its [model] table to change."""
    data = tomllib.loads((DATA / name).read_text())
    data["model"].update(model)
    config = parse_config(data)
    assert config.kinematics == "finite"
    structure = build_structure(config)
    assert structure.base.finite  # the runner hands the switch to the model
    return config, structure


def rotation(axis, angle_deg: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(angle_deg)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


# --- numba kernel == UFL form -----------------------------------------------------------------


def ufl_force(cell: SingleCell, laminate: Laminate, ppp: int, U: np.ndarray):
    """(8, 3) force and strain energy of the finite-kinematics UFL forms on one cell."""
    cell.set_displacement(U)
    groups = solid_shell.ply_groups(laminate, ppp)
    force = cell.assemble(
        solid_shell.internal_force_form(cell.u, cell.v, groups, kinematics="finite", bent=cell.bent)
    )
    energy = solid_shell.strain_energy_form(cell.u, groups, kinematics="finite", bent=cell.bent)
    return force, fem.assemble_scalar(fem.form(energy))


def large_displacement(rng: np.random.Generator, X: np.ndarray) -> np.ndarray:
    """A random rotation of up to 120 degrees plus random nodal displacements of 20 % of the
    element size: displacement gradients of order 1, far outside small strain."""
    R = rotation(rng.normal(size=3), rng.uniform(30.0, 120.0))
    return X @ (R - np.eye(3)).T + rng.normal(scale=0.2, size=(8, 3))


@pytest.mark.parametrize("ppp", [1, 2])
def test_numba_kernel_equals_ufl_form_finite(ppp):
    rng = np.random.default_rng(100 + ppp)
    laminate = random_laminate(rng, 5)
    rule = laminate_rule(laminate, ppp)
    worst_force, worst_energy, nonlinear = 0.0, 0.0, 0.0
    for _ in range(3):
        X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
        U = large_displacement(rng, X)
        f = np.empty((8, 3))
        energy = se.solid_shell_force(X, U, *rule, f, True)
        f_ufl, energy_ufl = ufl_force(SingleCell(X), laminate, ppp, U)
        worst_force = max(worst_force, relative_difference(f, f_ufl))
        worst_energy = max(worst_energy, abs(energy - energy_ufl) / energy_ufl)
        f_small = np.empty((8, 3))
        se.solid_shell_force(X, U, *rule, f_small)
        nonlinear = max(nonlinear, relative_difference(f_small, f_ufl))
    assert worst_force < ROUND_OFF, worst_force
    assert worst_energy < ROUND_OFF, worst_energy
    assert nonlinear > 0.1  # the states are far from linear: the comparison means something


def test_numba_subelement_equals_ufl_of_sublaminate_finite():
    """Plies 2..4 (0-based 1:4) of a 6-ply laminate as a subelement of a distorted parent,
    batched kernel with ``finite=True``."""
    rng = np.random.default_rng(110)
    laminate = random_laminate(rng, 6)
    first, stop = 1, 4
    f = laminate.ply_fractions
    X_parent = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
    X = subelement_vertices(X_parent, f, first, stop)
    sublaminate = Laminate(laminate.plies[first:stop])
    C = np.array(laminate.ply_stiffnesses()[first:stop])
    cell = SingleCell(X)
    for ppp in (1, 2):
        rules = se.concatenate_rules(
            [se.pack_rule(se.sublaminate_ply_zeta(f, first, stop), C, ppp)]
        )
        U = large_displacement(rng, X)
        f_all = np.empty((1, 8, 3))
        energy = se.solid_shell_forces(X[None], U[None], np.zeros(1, np.int64), *rules, f_all, True)
        f_ufl, energy_ufl = ufl_force(cell, sublaminate, ppp, U)
        assert relative_difference(f_all[0], f_ufl) < ROUND_OFF
        assert energy == pytest.approx(energy_ufl, rel=ROUND_OFF)


def test_finite_kernel_is_small_strain_kernel_for_small_displacements():
    """The Green-Lagrange terms are quadratic: at displacements 1e-7 of the element size the two
    kinematics agree to about 1e-7."""
    rng = np.random.default_rng(120)
    laminate = random_laminate(rng, 4)
    rule = laminate_rule(laminate, 1)
    X = distorted_hex(rng, BOX * [1.0, 1.0, laminate.thickness])
    U = rng.normal(scale=1e-7, size=(8, 3))
    f_small, f_finite = np.empty((8, 3)), np.empty((8, 3))
    se.solid_shell_force(X, U, *rule, f_small)
    se.solid_shell_force(X, U, *rule, f_finite, True)
    assert relative_difference(f_finite, f_small) < 1e-5


# --- rigid rotation and objectivity of a refined structure ------------------------------------


def refined_strip() -> Structure:
    """The 3 x 2 strip of ``finite_rotation.toml``: cell 0 refined weakly at interfaces 1 and 3
    and strongly at 2 (three subelements and a cohesive element), cell 1 strongly at 2, cell 2
    weakly at 3; cells 3-5 stay unrefined (neighbours of refined cells, so the border
    constraints are in play too)."""
    _, structure = finite_structure("finite_rotation.toml")
    requests = [
        (0, 1, InterfaceState.WEAK),
        (0, 2, InterfaceState.STRONG),
        (0, 3, InterfaceState.WEAK),
    ]
    requests += [(1, 2, InterfaceState.STRONG), (2, 3, InterfaceState.WEAK)]
    structure.refine(requests)
    assert len(structure.cohesive) == 2
    assert len(structure.base.ufl_cells[0]) == 3
    return structure


def set_motion(structure: Structure, motion) -> None:
    """u = motion(X) on every base and extra node (owned and ghosts)."""
    base = structure.base.u.x.array.reshape(-1, 3)
    base[:] = motion(structure.X_base)
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    structure.extra.vectors["u"].array.reshape(-1, 3)[:] = motion(X_extra)


def forces(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """Owned internal forces (n, 3) of the base and extra nodes."""
    structure.internal_force()
    blocks = structure.blocks
    return tuple(b.f.array[: b.n_owned].reshape(-1, 3).copy() for b in blocks)


def cohesive_forces(structure: Structure) -> tuple[np.ndarray, float]:
    """The cohesive elements' nodal forces alone (base and extra, stacked) and stored energy."""
    fb = np.zeros_like(structure.X_base)
    fx = np.zeros_like(structure.extra.vectors["X"].array.reshape(-1, 3))
    energy = add_cohesive_forces(
        structure.cohesive,
        structure.X_base,
        structure.extra.vectors["X"].array.reshape(-1, 3),
        structure.base.u.x.array.reshape(-1, 3),
        structure.extra.vectors["u"].array.reshape(-1, 3),
        fb,
        fx,
    )
    return np.vstack([fb, fx]), energy


STRAIN = np.array([[1.0, 0.3, 0.2], [0.3, -0.5, 0.4], [0.2, 0.4, 0.7]]) * 1e-3


@pytest.mark.slow
def test_rigid_rotation_of_refined_cells_gives_no_force():
    structure = refined_strip()
    set_motion(structure, lambda X: X @ STRAIN.T)
    scale = max(np.abs(f).max() for f in forces(structure))  # forces of a 1e-3 strain
    R = rotation((1.0, 2.0, 0.5), 90.0)
    set_motion(structure, lambda X: X @ (R - np.eye(3)).T)
    f_base, f_extra = forces(structure)
    residual = max(np.abs(f_base).max(), np.abs(f_extra).max()) / scale
    assert residual < 1e-10, residual
    solid, cohesive = structure.internal_forces.energies()
    assert abs(solid) < 1e-20
    assert cohesive == 0.0
    f_coh, energy = cohesive_forces(structure)
    assert np.all(f_coh == 0.0) and energy == 0.0  # no opening: not even round-off
    assert np.all(structure.cohesive.damage == 0.0)
    # small strain would see strains of order 1 in the same motion (what finite kinematics fix)
    structure.base.set_kinematics("small")
    assert max(np.abs(f).max() for f in forces(structure)) > 100.0 * scale


def test_rotated_state_gives_rotated_forces():
    """Objectivity: any deformed state (strain, noise on every node, the strong interfaces
    opened a little below the onset of damage) turned rigidly by R gives the same internal
    forces turned by R, through the UFL, subelement and cohesive paths alike."""
    structure = refined_strip()
    rng = np.random.default_rng(7)
    # openings up to about 1e-4 mm: below the onset openings N / K_n = 2e-4 mm, S / K_s = 4e-4 mm
    noise_base = rng.normal(scale=2e-5, size=structure.X_base.shape)
    noise_extra = rng.normal(scale=2e-5, size=structure.extra.vectors["X"].array.shape)
    noise_extra = noise_extra.reshape(-1, 3)
    u_base = structure.X_base @ STRAIN.T + noise_base
    u_extra = structure.extra.vectors["X"].array.reshape(-1, 3) @ STRAIN.T + noise_extra
    base = structure.base.u.x.array.reshape(-1, 3)
    extra = structure.extra.vectors["u"].array.reshape(-1, 3)

    def state(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        base[:] = (structure.X_base + u_base) @ R.T - structure.X_base
        X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
        extra[:] = (X_extra + u_extra) @ R.T - X_extra
        structure.follow_border()  # constrained extra nodes back on their masters
        return forces(structure)

    f_base, f_extra = state(np.eye(3))
    f_coh, stored = cohesive_forces(structure)
    assert np.abs(f_coh).max() > 1e-3 * np.abs(f_base).max()  # the interfaces are open
    assert stored > 0.0 and np.all(structure.cohesive.damage == 0.0)
    R = rotation((0.3, -1.0, 2.0), 75.0)
    g_base, g_extra = state(R)
    scale = np.abs(f_base).max()
    assert np.abs(g_base - f_base @ R.T).max() < 1e-10 * scale
    assert np.abs(g_extra - f_extra @ R.T).max() < 1e-10 * scale
    g_coh, stored_rotated = cohesive_forces(structure)
    assert np.abs(g_coh - f_coh @ R.T).max() < 1e-10 * np.abs(f_coh).max()
    assert stored_rotated == pytest.approx(stored, rel=1e-10)


# --- cantilever under a large tip load vs the elastica ----------------------------------------


def elastica(alpha: float, steps: int = 400) -> tuple[float, float, float]:
    """Inextensible, shear-rigid cantilever under a dead tip load P normal to its axis, alpha =
    P L^2 / EI: theta'' = -alpha cos(theta) on s in [0, 1], theta(0) = 0, theta'(1) = 0, solved by
    shooting on theta'(0) (bisection, RK4). Returns the tip deflection w / L, the shortening
    (L - x_tip) / L and the tip rotation theta(1) (rad)."""

    def shoot(kappa0: float) -> tuple[float, float, float, float]:
        h = 1.0 / steps
        theta, kappa, x, w = 0.0, kappa0, 0.0, 0.0
        for _ in range(steps):
            k1t, k1k = kappa, -alpha * math.cos(theta)
            k2t, k2k = kappa + 0.5 * h * k1k, -alpha * math.cos(theta + 0.5 * h * k1t)
            k3t, k3k = kappa + 0.5 * h * k2k, -alpha * math.cos(theta + 0.5 * h * k2t)
            k4t, k4k = kappa + h * k3k, -alpha * math.cos(theta + h * k3t)
            middle = theta + 0.5 * h * k2t
            new = theta + h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t)
            # x' = cos(theta), w' = sin(theta), Simpson over the step
            x += h / 6 * (math.cos(theta) + 4 * math.cos(middle) + math.cos(new))
            w += h / 6 * (math.sin(theta) + 4 * math.sin(middle) + math.sin(new))
            theta, kappa = new, kappa + h / 6 * (k1k + 2 * k2k + 2 * k3k + k4k)
        return kappa, theta, x, w

    low, high = 0.0, alpha  # the root curvature lies between 0 and the linear P L / EI
    for _ in range(50):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if shoot(middle)[0] > 0.0 else (middle, high)
    _, theta, x, w = shoot(0.5 * (low + high))
    return w, 1.0 - x, theta


def test_elastica_reference():
    """Small loads: the linear cantilever, w / L = alpha / 3, theta = alpha / 2; alpha = 2: the
    tabulated elastica (Bisshopp & Drucker 1945: w / L = 0.4935, shortening 0.1606)."""
    w, shortening, theta = elastica(1e-4)
    assert w == pytest.approx(1e-4 / 3, rel=1e-4)
    assert theta == pytest.approx(0.5e-4, rel=1e-4)
    w, shortening, _ = elastica(2.0)
    assert w == pytest.approx(0.4935, abs=2e-4)
    assert shortening == pytest.approx(0.1606, abs=2e-4)


def solve_newton(structure: Structure, load_steps: int = 8) -> int:
    """Static equilibrium of the base model's UFL form (all cells unrefined), the load factor
    running 0 -> 1 as the time of the config's linear load curve; Newton per load step.
    Returns the number of Newton iterations."""
    model, loads = structure.base, structure.loads
    V = model.V
    clamped = np.unique(loads.fixed // 3).astype(np.int32)
    assert len(loads.fixed) == 3 * len(clamped)  # whole nodes clamped: a blocked BC fits
    bc = fem.dirichletbc(np.zeros(3), clamped, V)
    tangent = fem.form(
        ufl.derivative(model.force_ufl, model.u, ufl.TrialFunction(V)), jit_options=JIT_OPTIONS
    )
    residual = fem.Function(V)
    correction = fem.Function(V)
    f_ext = np.zeros_like(residual.x.array)
    ksp = PETSc.KSP().create(model.comm)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    iterations = 0
    for step in range(1, load_steps + 1):
        loads.external_force(step / load_steps, f_ext)
        reference = np.linalg.norm(f_ext[: model.n_owned_dofs])
        for _ in range(25):
            model.internal_force(residual.x)  # owned entries complete
            residual.x.array[:] -= f_ext
            residual.x.array[loads.fixed] = 0.0
            norm = np.linalg.norm(residual.x.array[: model.n_owned_dofs])
            if model.comm.allreduce(norm**2) ** 0.5 < 1e-10 * reference:
                break
            A = fem_petsc.assemble_matrix(tangent, bcs=[bc])
            A.assemble()
            ksp.setOperators(A)
            ksp.solve(residual.x.petsc_vec, correction.x.petsc_vec)
            correction.x.scatter_forward()
            model.u.x.array[:] -= correction.x.array
            A.destroy()
            iterations += 1
        else:
            raise AssertionError(f"Newton did not converge in load step {step}")
    ksp.destroy()
    return iterations


@pytest.mark.slow
def test_cantilever_large_tip_load_matches_elastica():
    """[0]8 cantilever 100 x 2 x 2 mm, 40 cells, one element through the thickness, dead tip
    load P with P L^2 / EI = 2: tip deflection, shortening and rotation within 2 % of the
    elastica (EI = b / d11 of classical laminate theory, narrow beam). Then, in the same state,
    the element with the compatible thickness strain alone and without the shear correction
    (each subelement condenses its own enhanced strain and carries its own span's shear factor,
    so refinement is not an identity with either): every cell is refined weakly
    at interfaces 2, 4, 6 and the numba subelements carry the same nodal forces as the
    unrefined UFL element (the extra nodes' forces handed to the base nodes they
    interpolate)."""
    config, structure = finite_structure("finite_cantilever.toml")
    model = structure.base
    length, width = config.mesh.length, config.mesh.width
    EI = config.laminate.narrow_beam_bending_stiffness(width)
    alpha = config.loads[0].force[2] * length**2 / EI
    assert alpha == pytest.approx(2.0, rel=0.01)
    solve_newton(structure)

    u = model.u.x.array
    tip_w = u[face_dofs(model, "x1", "z")].mean()
    tip_u = u[face_dofs(model, "x1", "x")].mean()
    # tip rotation from the end face: the bottom-to-top vector turns from (0, 0, h) by theta
    X = model.V.tabulate_dof_coordinates()
    ends = face_dofs(model, "x1", "z") // 3
    top, bottom = ends[X[ends, 2] > X[:, 2].mean()], ends[X[ends, 2] < X[:, 2].mean()]
    x = X + u.reshape(-1, 3)
    d = x[top].mean(axis=0) - x[bottom].mean(axis=0)
    theta = math.atan2(-d[0], d[2])
    w_ref, shortening_ref, theta_ref = elastica(alpha)
    assert math.degrees(theta) > 30.0
    errors = {
        "deflection": tip_w / length / w_ref - 1.0,
        "shortening": -tip_u / length / shortening_ref - 1.0,
        "rotation": theta / theta_ref - 1.0,
    }
    assert max(abs(e) for e in errors.values()) < 0.02, errors

    # the same state through the numba subelements
    solved = model.u.x.array.copy()
    config, structure = finite_structure(
        "finite_cantilever.toml", enhanced_strain=False, shear_correction=False
    )
    model = structure.base
    # (where refinement places the new nodes, not where equilibrating them moves them)
    structure.stabilisation = dataclasses.replace(structure.stabilisation, equilibrate=False)
    model.u.x.array[:] = solved
    f_ufl = fem.Function(model.V).x
    model.internal_force(f_ufl)
    energy_ufl = model.strain_energy()
    f_ufl = f_ufl.array[: model.n_owned_dofs].reshape(-1, 3).copy()
    cells = range(model.n_owned_cells)
    structure.refine([(c, i, InterfaceState.WEAK) for c in cells for i in config.interfaces.refine])
    assert all(len(c) == 0 for c in model.ufl_cells)  # no unrefined cell is left
    f_base, f_extra = forces(structure)
    # hand each extra node's force to the two base nodes of its column (the transpose of its
    # interpolation at the interface's thickness fraction)
    n_interfaces = structure.interface_state.shape[1]
    fractions = structure.laminate.ply_fractions
    for node, key in enumerate(structure.extra.owned_keys):
        g, interface, _ = enr.key_parts(key, n_interfaces)
        bottom_node = structure.extra.local_base_node(g)
        share = fractions[interface]
        f_base[bottom_node] += (1.0 - share) * f_extra[node]
        f_base[structure.columns.top_of[bottom_node]] += share * f_extra[node]
    assert np.abs(f_base - f_ufl).max() < 1e-10 * np.abs(f_ufl).max()
    assert structure.internal_forces.energies()[0] == pytest.approx(energy_ufl, rel=1e-12)


# --- the config switch --------------------------------------------------------------------------


def test_kinematics_key():
    data = tomllib.loads((DATA / "finite_rotation.toml").read_text())
    assert parse_config(data).kinematics == "finite"
    del data["model"]["kinematics"]
    assert parse_config(data).kinematics == "small"  # the default
    data["model"]["kinematics"] = "large"
    with pytest.raises(InputError, match=r"^model\.kinematics: must be one of small, finite"):
        parse_config(data)
    # with ply damage the damaged cells co-rotate (tests/test_corotational.py): accepted
    impact = tomllib.loads((DATA / "mpi_one_rank_impact.toml").read_text())
    impact["model"]["kinematics"] = "finite"
    config = parse_config(impact)
    assert config.ply_damage and config.kinematics == "finite"
