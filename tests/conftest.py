"""Shared test helpers. mpi4py is imported before anything loads DOLFINx (the wheel needs it).

Units: N, mm, s, tonne.
"""

import pytest
from fenics_adaptive.meshes import esl_mesh
from mpi4py import MPI

from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.model.forms import LayeredModel, build_model

CROSS_PLY = [0, 90, 0, 90, 90, 0, 90, 0]


def prototype_material(name: str = "prototype", rho: float = 1.6e-9) -> PlyMaterial:
    """The paper's TCB ply (Table 1 as corrected in the issue)."""
    return PlyMaterial(name, E1=1e5, E2=1e4, G12=5e3, G23=4e3, nu12=0.25, nu23=0.25, rho=rho)


@pytest.fixture
def material() -> PlyMaterial:
    return prototype_material()


def esl_model(
    angles, length: float, width: float, nx: int, ny: int, ply_thickness: float = 0.25, **kw
) -> LayeredModel:
    laminate = Laminate.from_angles(prototype_material(), angles, ply_thickness)
    beam = esl_mesh(MPI.COMM_WORLD, length, width, nx, ny, laminate.thickness)
    return build_model(beam, [laminate], **kw)
