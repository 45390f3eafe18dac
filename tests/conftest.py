"""Shared fixtures. mpi4py is imported before anything loads DOLFINx (the wheel needs it).
The helpers the tests share are in ``helpers.py``.

Units: N, mm, s, tonne.
"""

import pytest
from helpers import prototype_material
from mpi4py import MPI  # noqa: F401

from fenics_adaptive.materials.laminate import PlyMaterial


@pytest.fixture
def material() -> PlyMaterial:
    return prototype_material()
