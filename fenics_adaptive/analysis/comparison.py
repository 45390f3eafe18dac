"""ESL against layerwise: the tools of ``demos/esl_vs_lw.py``.

Units: N, mm, s, tonne (stress MPa, energy mJ, time per step s).

- ``solve_linear_static``: the static equilibrium of any bonded, linear ``Structure`` (ESL,
  refined adaptive, layerwise). ``static.solve_static`` only knows the UFL cells of the base
  model; a refined element also has extra nodes and numba subelements. Its stiffness matrix is
  therefore *probed* from the package's own internal force (f_int is linear in u for these
  small-strain models, so column j of K is f_int(e_j); a structure with finite kinematics is
  refused, since its probed "matrix" would depend on the probe's size and the answer be
  wrong without a warning): with a distance-2 colouring of the nodes
  one force evaluation gives the columns of all nodes of one colour and one component at once
  (no two of them share a neighbour, so every force entry comes from exactly one of them), about
  80 evaluations for a layerwise beam. The sparse system is solved directly (PETSc LU) and the
  answer checked against the package's force: ``StaticResult.residual`` is
  |f_ext - f_int(u)| over the free DOFs / |f_ext| there (or the reactions' norm when only
  prescribed displacements load the body), evaluated with ``Structure.internal_force``,
  not with the probed matrix. Serial only (the probing reads node neighbourhoods locally).
- stresses each model offers through the thickness: per-ply constitutive stresses at the ply
  mid-points (``column_ply_stresses``), their interface values as a post-processor shows them
  (``ply_values_at_interfaces``), and, for models with nodes at the interfaces (refined,
  layerwise), the traction each interface transmits (``interface_tractions``): the internal
  force that the elements above an interface put on its nodes, per unit tributary area: what a
  cohesive element in that interface would carry; exact equilibrium of the discrete solution,
  independent of any recovery. ESL recovery: ``indicators.recovered_interface_stresses``.
- the element forces behind those tractions (``element_forces``) are the structure's own: the
  integration rule of every span of plies from its ``rule_table`` (the one its kernels, masses
  and ply damage use; a one-ply subelement has at least two points through its thickness,
  whatever ``points_per_ply`` says), its kinematics (small or finite). Summed over all elements,
  less the cohesive forces, after the border's transfer, they are ``Structure.internal_force``
  (``tests/test_rule_table.py``). A structure with ply damage is refused: its forces depend on
  the damage of every (cell, ply), which undamaged element forces cannot reproduce.
- ``CantileverBeamTheory``: laminated (narrow) beam theory of a cantilever under a uniform
  line load: classical laminate theory in bending, transverse shear and normal stresses from
  integrating equilibrium through the thickness, Timoshenko deflection with the laminate's
  shear compliance.

Stress vectors through the thickness are ordered (sigma_zz, tau_xz, tau_yz) ("out-of-plane"
components, ``OUT_OF_PLANE``) at the n_plies + 1 ply boundaries, bottom face (0) to top face.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fenics_adaptive.adaptivity.indicators import ply_stresses
from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.materials.laminate import Laminate, reduced_plane_stress_stiffness
from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces
from fenics_adaptive.model.loading import face_nodes
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.solver import equilibrium
from fenics_adaptive.solver.equilibrium import SparseMatrix

OUT_OF_PLANE = ("sigma_zz", "tau_xz", "tau_yz")
VOIGT_OUT_OF_PLANE = [2, 4, 3]  # Voigt (xx, yy, zz, yz, xz, xy) indices of OUT_OF_PLANE


# ----------------------------------------------------------------------------- static solution
def _combined_arrays(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """(displacement, internal force) of base + extra DOFs as the solver keeps them."""
    u = np.concatenate([structure.base.u.x.array, structure.extra.vectors["u"].array])
    f = np.concatenate([structure.f_base.array, structure.f_extra.array])
    return u, f


def _check_bonded_serial(structure: Structure) -> None:
    """The probing and the per-node sums here read node neighbourhoods on one rank, and the
    element forces leave out cohesive elements and ply damage: refuse anything else."""
    if structure.comm.size > 1:
        raise RuntimeError("comparison: serial only (run the comparison on one rank)")
    if len(structure.cohesive) or structure.ply_damage:
        raise ValueError("comparison: cohesive elements or ply damage make it nonlinear")
    if len(structure.border):
        raise ValueError(
            "comparison: constrained border extra nodes (partly refined regions) are "
            "not supported; refine every cell at the same interfaces"
        )


def _check_small_strain(structure: Structure) -> None:
    """A probed matrix is the stiffness only of a structure whose force is linear in u."""
    if structure.base.finite:
        raise ValueError(
            "comparison: the structure has finite kinematics, whose internal force is not "
            "linear in u: a probed stiffness (and a linear static solution) would be wrong; "
            'build it with kinematics = "small"'
        )


def probe_stiffness(structure: Structure) -> tuple[SparseMatrix, int]:
    """K of the structure (base then extra DOFs, 3 per node) from its internal force; returns
    (K, number of force evaluations). Raises ValueError for cohesive elements, ply damage,
    border constraints or finite kinematics (the force is then not linear in u), RuntimeError
    on more than one rank."""
    _check_bonded_serial(structure)
    _check_small_strain(structure)
    system = equilibrium.StaticSystem(structure, 0.0)
    zero = np.zeros(system.n)
    return system.tangent(zero, system.resisting_force(zero), 1.0)


@dataclass
class StaticResult:
    """Static equilibrium and how well it holds."""

    dofs: int
    force_evaluations: int
    residual: float  # |f_ext - f_int(u)| / |f_ext| on the free DOFs, package's f_int
    asymmetry: float  # max |K - K^T| / max |K| of the probed matrix
    applied_force: np.ndarray  # N, resultant of the loads
    reaction_force: np.ndarray  # N, resultant of f_int - f_ext on the prescribed DOFs
    external_work: float  # mJ, 1/2 f_ext . u (Clapeyron)
    strain_energy: float  # mJ, the structure's own energy of the solution
    wall_time: float  # s

    def summary(self) -> dict:
        return {
            "dofs": self.dofs,
            "force_evaluations_to_probe_K": self.force_evaluations,
            "relative_residual": self.residual,
            "stiffness_asymmetry": self.asymmetry,
            "applied_force_N": self.applied_force.tolist(),
            "reaction_force_N": self.reaction_force.tolist(),
            "half_external_work_mJ": self.external_work,
            "strain_energy_mJ": self.strain_energy,
            "wall_time_s": self.wall_time,
        }


def equilibrium_residual(structure: Structure, t: float = 0.0) -> float:
    """|f_ext - f_int(u)| / |f_ext| over the free DOFs at the structure's current displacement
    (``Structure.internal_force``, the force the explicit solver uses)."""
    _check_bonded_serial(structure)
    system = equilibrium.StaticSystem(structure, t)
    f_ext, free = system.f_ext, system.free
    structure.internal_force()
    f_int = _combined_arrays(structure)[1]
    return float(np.linalg.norm((f_ext - f_int)[free]) / np.linalg.norm(f_ext[free]))


def solve_linear_static(structure: Structure, t: float = 0.0) -> StaticResult:
    """Static equilibrium of a bonded linear structure under its loads and prescribed motions
    at time t; the displacement is left in the structure (base and extra vectors). Refuses
    what ``probe_stiffness`` refuses (finite kinematics among them: ValueError)."""
    start = time.perf_counter()
    _check_bonded_serial(structure)
    _check_small_strain(structure)
    system = equilibrium.StaticSystem(structure, t)
    solution = equilibrium.solve(system)
    u, f_int = solution.u, solution.resisting_force
    reaction = np.zeros(system.n)
    reaction[system.fixed] = (f_int - system.f_ext)[system.fixed]
    solid, _ = structure.internal_forces.energies()
    return StaticResult(
        dofs=system.n,
        force_evaluations=solution.force_evaluations,
        residual=solution.residual,
        asymmetry=solution.tangent.asymmetry(),
        applied_force=system.f_ext.reshape(-1, 3).sum(axis=0),
        reaction_force=reaction.reshape(-1, 3).sum(axis=0),
        external_work=0.5 * float(np.dot(system.f_ext, u)),
        strain_energy=float(solid),
        wall_time=time.perf_counter() - start,
    )


# ----------------------------------------------------------------------------- stresses
def cell_columns(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """(column index of every owned cell, in-plane centroid (n_columns, 2) of every column): an
    ESL or adaptive cell is its own column; the cells of a layerwise model stacked above one
    in-plane cell form one column."""
    centroids = structure.X_base[structure.bottom_local][:, :, :2].mean(axis=1)
    scale = 1e-6 * max(float(np.ptp(structure.X_base[:, 0])), 1.0)
    keys = np.round(centroids / scale).astype(np.int64)
    _, first, column = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return column.ravel(), centroids[first]


def column_ply_stresses(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """(n_columns, n_plies, 6) constitutive stress (MPa, Voigt, shell frame) at the mid-point of
    every ply of every column, from whichever element holds the ply; and the column centroids
    (n_columns, 2)."""
    column, centroids = cell_columns(structure)
    stresses = ply_stresses(structure)  # zero for plies a (layerwise) cell does not hold
    out = np.zeros((len(centroids), *stresses.shape[1:]))
    np.add.at(out, column, stresses)
    return out, centroids


def ply_values_at_interfaces(stresses: np.ndarray) -> np.ndarray:
    """(n, n_plies + 1, 3) out-of-plane stresses at the ply boundaries as a post-processor shows
    the constitutive ones: the mean of the two plies at an interface, the outer ply's value on
    the faces. ``stresses``: (n, n_plies, 6)."""
    values = stresses[:, :, VOIGT_OUT_OF_PLANE]
    out = np.empty((values.shape[0], values.shape[1] + 1, 3))
    out[:, 0], out[:, -1] = values[:, 0], values[:, -1]
    out[:, 1:-1] = 0.5 * (values[:, :-1] + values[:, 1:])
    return out


def element_forces(structure: Structure, mask: np.ndarray) -> np.ndarray:
    """Internal force (N, (n_nodes, 3), base then extra nodes) of the elements
    ``structure.elements()[mask]`` alone, at the current displacement (numba kernel), as the
    structure computes them: the rule of each span of plies from ``structure.rule_table``, the
    structure's kinematics (``structure.base.finite``). Cohesive elements are not included; the
    forces are this rank's, on the nodes the elements name (no border transfer, no reverse
    scatter). Raises ValueError for a structure with ply damage (its elements' forces depend
    on a damage state these cannot reproduce)."""
    if structure.ply_damage:
        raise ValueError(
            "comparison.element_forces: the structure has ply damage; its element forces "
            "depend on the damage state of every (cell, ply), which undamaged element forces "
            "cannot reproduce"
        )
    nodes, cells, plies = structure.elements()
    n_extra = structure.extra.n_local
    f_base = np.zeros((structure.n_base, 3))
    f_extra = np.zeros((n_extra, 3))
    if mask.any():
        # the structure's own rules and kinematics: a copy of either drifts (a one-ply rule
        # packed with points_per_ply missed the table's two points: 15 % off the structure's
        # force; small strain on a finite-kinematics structure)
        table = structure.rule_table
        elements = SubelementSet(
            np.ascontiguousarray(nodes[mask]),
            table.rule_of(plies[mask]),
            table.packed,
            frames=structure.base.element_frames(cells[mask]),
        )
        add_subelement_forces(
            elements,
            structure.X_base,
            structure.extra.vectors["X"].array.reshape(-1, 3),
            structure.base.u.x.array.reshape(-1, 3),
            structure.extra.vectors["u"].array.reshape(-1, 3),
            f_base,
            f_extra,
            structure.base.finite,
        )
    return np.vstack([f_base, f_extra])


def interface_tractions(structure: Structure) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Width-averaged out-of-plane stresses each interface transmits, per line of nodes across
    the width: {interface (1-based): (x of the lines (m,), (m, 3) sigma_zz, tau_xz, tau_yz)}.
    Only interfaces with nodes of their own (refined or layerwise); the ESL element has none.

    The elements above interface i, a free body loaded on its top face only, are held by the
    force F that the lower part applies to the interface nodes: F equals their internal force
    there. The traction on the upper body's bottom face (outward normal -z) is -(tau_xz, tau_yz,
    sigma_zz), hence the stresses -F / A per line, A the lines' tributary area (the reference
    area: with finite kinematics these are nominal tractions, in the global axes)."""
    _check_bonded_serial(structure)
    nodes, _, plies = structure.elements()
    X = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
    tol = 1e-6 * max(float(np.ptp(X[:, 0])), 1.0)
    out = {}
    for interface in range(1, structure.laminate.n_plies):
        starts_here = plies[:, 0] == interface
        if not starts_here.any():
            continue
        F = element_forces(structure, plies[:, 0] >= interface)
        faces = nodes[starts_here][:, :4]  # bottom faces of the elements right above
        areas = np.repeat(quad_areas(X[faces]) / 4.0, 4)
        on = np.unique(faces)
        area = np.bincount(faces.ravel(), weights=areas, minlength=len(X))[on]
        lines, line = np.unique(np.round(X[on, 0] / tol).astype(np.int64), return_inverse=True)
        line = line.ravel()
        force = np.stack([np.bincount(line, weights=F[on, k]) for k in (2, 0, 1)], axis=1)
        area_line = np.bincount(line, weights=area)
        out[interface] = (lines * tol, -force / area_line[:, None])
    return out


def tip_deflection(structure: Structure, face: str = "x1") -> float:
    """Downward deflection (mm, positive down) of the end ``face``: mean -u_z of its bottom and
    top edge nodes (nodes every model has: ESL, refined and layerwise alike)."""
    model = structure.base
    nodes = np.union1d(face_nodes(model, f"{face}&bottom"), face_nodes(model, f"{face}&top"))
    return -float(model.u.x.array.reshape(-1, 3)[nodes, 2].mean())


# ----------------------------------------------------------------------------- beam theory
@dataclass(frozen=True)
class CantileverBeamTheory:
    """Narrow laminated cantilever (clamped at x = 0, free at x = L, width b, free sides) under
    a uniform downward line load q = total_force / L on its top face.

    Bending: classical laminate theory with N = 0, M_y = M_xy = 0 (narrow beam): a moment M
    (N mm) curves it by kappa = d[3:, 3] M / b (d = inv(ABD)); ply stresses Q_k (eps0 + z
    kappa). M(x) = q (L - x)^2 / 2 (top in tension), V(x) = q (L - x).
    Out-of-plane stresses from equilibrium, averaged over the width (the side faces are free):
    tau_xz(z) = V int_{-h/2}^{z} s_xx, tau_yz(z) = V int s_xy, sigma_zz(z) = q int_{-h/2}^{z}
    S_xx, with s the ply stress per unit moment and S_xx = int s_xx; sigma_zz(top) = -q / b, the
    applied pressure. Deflection (Timoshenko): w(L) = q L^4 / (8 EI) + q L^2 / (2 kGA), EI =
    b / d11, 1 / kGA = b int S_xx^2 / G_xz dz (the shear compliance of the exact shear flow,
    G_xz = 1 / S55 of each ply)."""

    laminate: Laminate
    length: float  # mm
    width: float  # mm
    total_force: float  # N, downward

    @property
    def q(self) -> float:
        return self.total_force / self.length  # N/mm

    @property
    def _z(self) -> np.ndarray:
        h = self.laminate.thickness
        return self.laminate.ply_fractions * h - 0.5 * h

    def _per_unit_moment(self) -> tuple[np.ndarray, np.ndarray]:
        """Per ply k, coefficients (a_k, b_k) with (s_xx, s_yy, s_xy)(z) = a_k + b_k z, the ply
        stresses (MPa) per unit bending moment (N mm)."""
        d = np.linalg.inv(self.laminate.abd())
        eps0, kappa = d[:3, 3] / self.width, d[3:, 3] / self.width
        Q = [reduced_plane_stress_stiffness(p.stiffness()) for p in self.laminate.plies]
        return np.array([q @ eps0 for q in Q]), np.array([q @ kappa for q in Q])

    @property
    def EI(self) -> float:
        return self.laminate.narrow_beam_bending_stiffness(self.width)

    def moment(self, x: np.ndarray | float) -> np.ndarray:
        return 0.5 * self.q * (self.length - np.asarray(x, dtype=float)) ** 2

    def shear_force(self, x: np.ndarray | float) -> np.ndarray:
        return self.q * (self.length - np.asarray(x, dtype=float))

    def ply_in_plane(self, x: np.ndarray | float) -> np.ndarray:
        """(n_plies, 3) sigma_xx, sigma_yy, tau_xy (MPa) at the ply mid-points, moment M(x)
        (x may be an array: the mean over those sections)."""
        a, b = self._per_unit_moment()
        z = self._z
        mid = 0.5 * (z[:-1] + z[1:])
        return float(np.mean(self.moment(x))) * (a + b * mid[:, None])

    def _first_integrals(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """S_xx(z), S_xy(z) = int_{-h/2}^{z} s dz' and T(z) = int_{-h/2}^{z} S_xx dz', exactly:
        within ply k, s = a_k + b_k z integrates to a quadratic, S_xx to a cubic."""
        a, b = self._per_unit_moment()
        zb = self._z

        def in_ply(k, s, S0, T0):  # S (3,) and T at height s of ply k from their bottom values
            lo = zb[k]
            S = S0 + a[k] * (s - lo) + 0.5 * b[k] * (s**2 - lo**2)
            offset = S0[0] - a[k, 0] * lo - 0.5 * b[k, 0] * lo**2  # S_xx = offset + a z + b z^2/2
            T = (
                T0
                + offset * (s - lo)
                + 0.5 * a[k, 0] * (s**2 - lo**2)
                + b[k, 0] * (s**3 - lo**3) / 6.0
            )
            return S, T

        S_bottom, T_bottom = [np.zeros(3)], [0.0]  # at each ply's bottom
        for k in range(len(a)):
            S, T = in_ply(k, zb[k + 1], S_bottom[k], T_bottom[k])
            S_bottom.append(S)
            T_bottom.append(T)
        z = np.clip(np.atleast_1d(np.asarray(z, dtype=float)), zb[0], zb[-1])
        ply = np.clip(np.searchsorted(zb, z, side="right") - 1, 0, len(a) - 1)
        values = [in_ply(k, s, S_bottom[k], T_bottom[k]) for k, s in zip(ply, z, strict=True)]
        S = np.array([v[0] for v in values]).reshape(-1, 3)
        T = np.array([v[1] for v in values])
        return S[:, 0], S[:, 2], T

    def out_of_plane(self, x: np.ndarray | float, z: np.ndarray | None = None) -> np.ndarray:
        """(len(z), 3) width-averaged sigma_zz, tau_xz, tau_yz (MPa) at heights z from the
        mid-plane (default: the ply boundaries), at section(s) x (mean over them)."""
        z = self._z if z is None else np.asarray(z, dtype=float)
        S_xx, S_xy, T = self._first_integrals(z)
        V = float(np.mean(self.shear_force(x)))
        return np.stack([self.q * T, V * S_xx, V * S_xy], axis=1)

    def shear_compliance(self) -> float:
        """1 / kGA (1/N): complementary shear energy of the exact shear flow per V^2 / 2."""
        zb = self._z
        total = 0.0
        for k, ply in enumerate(self.laminate.plies):
            G_xz = 1.0 / np.linalg.inv(ply.stiffness())[4, 4]
            s, w = np.polynomial.legendre.leggauss(4)
            z = 0.5 * (zb[k] + zb[k + 1]) + 0.5 * (zb[k + 1] - zb[k]) * s
            S_xx = self._first_integrals(z)[0]
            total += 0.5 * (zb[k + 1] - zb[k]) * np.dot(w, S_xx**2) / G_xz
        return self.width * total

    def tip_deflection(self) -> dict:
        bending = self.q * self.length**4 / (8.0 * self.EI)
        shear = self.q * self.length**2 / 2.0 * self.shear_compliance()
        return {"bending_mm": bending, "shear_mm": shear, "total_mm": bending + shear}


def first_bending_period(theory: CantileverBeamTheory) -> float:
    """Euler-Bernoulli cantilever: omega_1 = 1.8751^2 sqrt(EI / (rho A L^4)) (s)."""
    rho_A = theory.laminate.areal_mass() * theory.width
    omega = 1.8751**2 * math.sqrt(theory.EI / (rho_A * theory.length**4))
    return 2.0 * math.pi / omega
