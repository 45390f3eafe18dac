"""The thickness strain sampled on the vertical edges of cells whose directors bend
(``element.assumed_strain``): its definition, checked from the nodes by a second path; where it
acts and where not; rigid motions.

The kernels and the UFL form compute it from monomial coefficients and from second derivatives
(``tests/test_subelement.py``, ``test_batched.py``, ``test_finite_rotation.py`` hold those two
equal on distorted cells). Here the energy of a cell whose only stiffness is C_zz,zz is rebuilt
in numpy from the definition: the covariant thickness strain on the four vertical edges, where
it is exact, interpolated along xi and along eta (``assumed_strain``'s module docstring).
Units: mm, MPa, mJ.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import BOX, CARBON, distorted_hex

from fenics_adaptive.element import solid_shell
from fenics_adaptive.element import subelement as se
from fenics_adaptive.element.assumed_strain import cells_with_bent_directors
from fenics_adaptive.materials.laminate import Laminate

C_ZZ = 1.0e4  # MPa


def _only_zz() -> np.ndarray:
    C = np.zeros((1, 6, 6))
    C[0, 2, 2] = C_ZZ
    return C


def _shape_gradients(point: np.ndarray) -> np.ndarray:
    """(8, 3) d N_a / d(xi, eta, zeta) of the trilinear shape functions at ``point``."""
    out = np.empty((8, 3))
    for a, corner in enumerate(se.CORNERS):
        factors = [c * p + (1 - c) * (1 - p) for c, p in zip(corner, point, strict=True)]
        for r in range(3):
            rest = np.prod([factors[s] for s in range(3) if s != r])
            out[a, r] = (1.0 if corner[r] else -1.0) * rest
    return out


def _edge_field(edges: np.ndarray, xi: float, eta: float) -> np.ndarray:
    """Bilinear interpolation of the four vertical edges' vectors (4, 3), tensor order."""
    return (
        (1 - xi) * (1 - eta) * edges[0]
        + xi * (1 - eta) * edges[1]
        + (1 - xi) * eta * edges[2]
        + xi * eta * edges[3]
    )


def reference_energy(X: np.ndarray, U: np.ndarray, finite: bool) -> float:
    """Strain energy (mJ) of a one-ply cell whose only stiffness is C_zz,zz, from the
    definition: Cartesian e_zz of the compatible strain plus dE k_z^2, with dE the edge-sampled
    covariant thickness strain less the compatible one, E^s = I_xi f + I_eta f - f."""
    A_edges = X[4:] - X[:4]
    b_edges = U[4:] - U[:4]

    def f(xi, eta):  # the compatible covariant thickness strain on the line (xi, eta)
        a, b = _edge_field(A_edges, xi, eta), _edge_field(b_edges, xi, eta)
        return a @ b + (0.5 * b @ b if finite else 0.0)

    points, weights = solid_shell.ply_rules(0.0, 1.0, 2)["normal"]
    energy = 0.0
    for point, weight in zip(points, weights, strict=True):
        xi, eta, _ = point
        dN = _shape_gradients(point)
        J = X.T @ dN  # dx_i / dX_r
        K = np.linalg.inv(J)
        H = (U.T @ dN) @ K
        e_zz = H[2, 2] + (0.5 * (H[:, 2] @ H[:, 2]) if finite else 0.0)
        sampled = (1 - xi) * f(0.0, eta) + xi * f(1.0, eta) + (1 - eta) * f(xi, 0.0)
        sampled += eta * f(xi, 1.0) - f(xi, eta)
        e_zz += (sampled - f(xi, eta)) * K[2, 2] ** 2
        energy += weight * abs(np.linalg.det(J)) * 0.5 * C_ZZ * e_zz**2
    return energy


def bent_hex(rng: np.random.Generator) -> np.ndarray:
    """A distorted hexahedron whose vertical edges are far from parallel and, unlike those of
    a cylinder's cells, twisted (x,zeta xi eta != 0)."""
    X = distorted_hex(rng, amount=0.15)
    assert cells_with_bent_directors(X[None])[0]
    return X


@pytest.mark.parametrize("finite", [False, True])
def test_kernel_energy_is_the_edge_sampled_thickness_strain(finite):
    """On bent distorted cells under random displacements (large ones under finite
    kinematics) the kernel's energy equals the one rebuilt from the definition to round-off,
    and differs from the compatible strain's: the correction acts."""
    rng = np.random.default_rng(11)
    rule = se.pack_rule(np.array([0.0, 1.0]), _only_zz(), 2)
    for _ in range(4):
        X = bent_hex(rng)
        U = rng.normal(scale=0.2 if finite else 1e-3, size=(8, 3))
        f = np.empty((8, 3))
        energy = se.solid_shell_force(X, U, *rule, f, finite)
        assert energy == pytest.approx(reference_energy(X, U, finite), rel=1e-11)
        # the compatible energy: the same cell with parallel edges has no correction
        assert abs(energy - _compatible_energy(X, U, finite)) > 1e-6 * energy


def _compatible_energy(X: np.ndarray, U: np.ndarray, finite: bool) -> float:
    points, weights = solid_shell.ply_rules(0.0, 1.0, 2)["normal"]
    energy = 0.0
    for point, weight in zip(points, weights, strict=True):
        dN = _shape_gradients(point)
        J = X.T @ dN
        H = (U.T @ dN) @ np.linalg.inv(J)
        e_zz = H[2, 2] + (0.5 * (H[:, 2] @ H[:, 2]) if finite else 0.0)
        energy += weight * abs(np.linalg.det(J)) * 0.5 * C_ZZ * e_zz**2
    return energy


@pytest.mark.parametrize("finite", [False, True])
def test_cells_with_parallel_edges_keep_the_compatible_strain(finite):
    """Vertical edges parallel, the rest distorted: no correction, small or finite strain."""
    rng = np.random.default_rng(12)
    rule = se.pack_rule(np.array([0.0, 1.0]), _only_zz(), 2)
    X = distorted_hex(rng, amount=0.15)
    X[4:] = X[:4] + np.array([0.1, -0.05, BOX[2]])
    assert not cells_with_bent_directors(X[None])[0]
    U = rng.normal(scale=0.2 if finite else 1e-3, size=(8, 3))
    f = np.empty((8, 3))
    energy = se.solid_shell_force(X, U, *rule, f, finite)
    assert energy == pytest.approx(_compatible_energy(X, U, finite), rel=1e-12)


def test_rigid_motions_of_bent_cells_carry_no_force():
    """A bent laminate cell moved rigidly: an infinitesimal rotation (small strain) and a
    rotation by 70 degrees (finite) leave the edge-sampled strain zero: no force, no energy."""
    rng = np.random.default_rng(13)
    C = np.array(Laminate.from_angles(CARBON, [30.0], 1.0).ply_stiffnesses())
    rule = se.pack_rule(np.array([0.0, 1.0]), C, 2, enhanced=True)
    X = bent_hex(rng)
    omega = rng.normal(size=3) * 1e-3
    cases = [(np.cross(omega, X) + 0.01, False)]
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = np.radians(70.0)
    W = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(a) * W + (1 - np.cos(a)) * W @ W
    cases.append((X @ (R - np.eye(3)).T + 0.3, True))
    for U, finite in cases:
        f = np.empty((8, 3))
        energy = se.solid_shell_force(X, U, *rule, f, finite)
        strained = np.empty((8, 3))
        se.solid_shell_force(X, U + 1e-3 * rng.normal(size=(8, 3)), *rule, strained, finite)
        assert np.abs(f).max() < 1e-9 * np.abs(strained).max()
        assert abs(energy) < 1e-12


@pytest.mark.parametrize("finite", [False, True])
def test_a_batch_mixing_bent_and_parallel_cells_equals_the_cells_alone(finite):
    """The batched kernel takes up to 16 cells of one rule together: where bent and parallel
    cells share a batch, each cell's force and the energy equal the one-element kernel's (a
    parallel cell gets no force through dE, under finite strain too)."""
    from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces

    rng = np.random.default_rng(14)
    C = np.array(Laminate.from_angles(CARBON, [0.0, 45.0, 90.0], 1.0 / 3).ply_stiffnesses())
    rule = se.pack_rule(np.array([0.0, 1 / 3, 2 / 3, 1.0]), C, 2, enhanced=True)
    X = np.array([distorted_hex(rng, amount=0.15) for _ in range(6)])
    X[1::2, 4:] = X[1::2, :4] + np.array([0.05, 0.0, BOX[2]])  # every other cell: parallel
    assert list(cells_with_bent_directors(X)) == [True, False] * 3
    U = rng.normal(scale=0.2 if finite else 1e-3, size=X.shape)
    cells = SubelementSet(
        np.arange(8 * len(X), dtype=np.int32).reshape(-1, 8),
        np.zeros(len(X), dtype=np.int64),
        se.concatenate_rules([rule]),
    )
    f = np.zeros((8 * len(X), 3))
    none = np.zeros((0, 3))
    energy = add_subelement_forces(
        cells, X.reshape(-1, 3), none, U.reshape(-1, 3), none, f, none, finite
    )
    alone = np.empty((len(X), 8, 3))
    energies = [se.solid_shell_force(X[e], U[e], *rule, alone[e], finite) for e in range(len(X))]
    assert energy == pytest.approx(sum(energies), rel=1e-12)
    for e in range(len(X)):
        scale = np.abs(alone[e]).max()
        assert np.abs(f.reshape(-1, 8, 3)[e] - alone[e]).max() < 1e-11 * scale, e
