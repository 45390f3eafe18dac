"""Shared fixtures. mpi4py is imported before anything loads DOLFINx (the wheel needs it).
The helpers the tests share are in ``helpers.py``.

Units: N, mm, s, tonne.
"""

import pytest
from helpers import prototype_material
from mpi4py import MPI  # noqa: F401

from fenics_adaptive.materials.laminate import PlyMaterial

# Every MPI run and every documentation build takes more than a few seconds: such tests are slow
# whether or not they say so (python -m pytest tests -m "not slow" leaves them out).
ALWAYS_SLOW = ("mpi", "docs")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if any(item.get_closest_marker(name) for name in ALWAYS_SLOW):
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def material() -> PlyMaterial:
    return prototype_material()
