"""The shell obstacle course (MacNeal and Harder 1985; Belytschko et al. 1985) on the solid
shell: the Scordelis-Lo roof and the pinched cylinder with rigid diaphragms, one ESL cell
through the thickness, solved statically (``solver.static``). Each returns its displacement
over the reference value; ``benchmarks/shells.py`` tabulates and plots them,
``tests/test_shell.py`` holds their convergence.

Units: the cases' own consistent ones (the classics give E, lengths and loads without units).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.meshes import shell, surface
from fenics_adaptive.model.forms import LayeredModel, build_model
from fenics_adaptive.model.loading import resolve
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, PrescribedMotion
from fenics_adaptive.solver.static import solve_static

SCORDELIS_LO = 0.3024  # vertical displacement at the middle of the free edge
PINCHED_CYLINDER = 1.8248e-5  # radial displacement under the load


def isotropic(E: float, nu: float) -> PlyMaterial:
    """An isotropic ply material of modulus ``E`` and Poisson ratio ``nu`` (density 1)."""
    G = E / (2 * (1 + nu))
    return PlyMaterial(name="iso", E1=E, E2=E, G12=G, G23=G, nu12=nu, nu23=nu, rho=1.0)


def fixed(face: str, component: str) -> PrescribedMotion:
    """``component`` of the nodes of ``face`` held at zero."""
    return PrescribedMotion(face, component, "displacement", 0.0, Amplitude.constant(0.0))


def cylinder(
    radius: float, length: float, angle: float, n: int, laminate: Laminate
) -> LayeredModel:
    """The ESL model of a cylindrical panel about x, from the crown (theta = 0) to ``angle``
    degrees, ``n`` x ``n`` cells, normals outward, axis 1 along x."""
    beam = shell.shell_mesh(
        MPI.COMM_WORLD,
        surface.panel(radius, length, angle, n, n, start=0.0),
        [laminate.thickness],
        direction=shell.axial_direction([1.0, 0.0, 0.0]),
        outward=lambda p: p * [0.0, 1.0, 1.0],
    )
    return build_model(beam, [laminate])


def _same_material_plies(material: PlyMaterial, thickness: float, plies: int) -> Laminate:
    """One ply, or four of the same material at 0/90/0/90 (the same stiffness, integrated
    ply by ply)."""
    angles = [0] if plies == 1 else [0, 90, 0, 90]
    return Laminate.from_angles(material, angles, thickness / len(angles))


def scordelis_lo(n: int, plies: int = 1) -> float:
    """The Scordelis-Lo roof (R 25, L 50, 80 degrees, t 0.25, E 4.32e8, nu 0, gravity 90 per
    unit area, rigid diaphragms at the ends), a quarter meshed n x n: the vertical
    displacement at the middle of the free edge over ``SCORDELIS_LO``."""
    model = cylinder(25.0, 25.0, 40.0, n, _same_material_plies(isotropic(4.32e8, 0.0), 0.25, plies))
    motions = [fixed("x0", "y"), fixed("x0", "z"), fixed("x1", "x"), fixed("theta0", "y")]
    weight = -90.0 * 25.0 * np.radians(40.0) * 25.0
    loads = resolve(model, motions, [FaceLoad("top", (0.0, 0.0, weight), Amplitude.constant())])
    u = solve_static(model, motions, loads, 0.0).reshape(-1, 3)
    x = model.V.tabulate_dof_coordinates()
    theta = np.degrees(np.arctan2(x[:, 1], x[:, 2]))
    edge = (np.abs(x[:, 0] - 25.0) < 1e-6) & (np.abs(theta - 40.0) < 1e-6)
    return -float(u[edge, 2].mean()) / SCORDELIS_LO


def pinched_cylinder(n: int, plies: int = 1) -> float:
    """The pinched cylinder with rigid diaphragms (R 300, L 600, t 3, E 3e6, nu 0.3, two
    opposite loads P = 1 at mid-length), an eighth meshed n x n: the radial displacement under
    the load over ``PINCHED_CYLINDER``."""
    model = cylinder(300.0, 300.0, 90.0, n, _same_material_plies(isotropic(3.0e6, 0.3), 3.0, plies))
    motions = [fixed("x0", "y"), fixed("x0", "z"), fixed("x1", "x")]
    motions += [fixed("theta0", "y"), fixed("theta1", "z")]
    loads = resolve(model, motions, [])
    x = model.V.tabulate_dof_coordinates()
    under = np.flatnonzero((np.abs(x[:, 0] - 300.0) < 1e-6) & (np.abs(x[:, 1]) < 1e-6))
    base = loads.external_force

    def external_force(t, out):  # P / 4 on the eighth, shared by the nodes through the wall
        base(t, out)
        out[3 * under + 2] -= 0.25 / len(under)

    loads.external_force = external_force
    u = solve_static(model, motions, loads, 0.0).reshape(-1, 3)
    return -float(u[under, 2].mean()) / PINCHED_CYLINDER
