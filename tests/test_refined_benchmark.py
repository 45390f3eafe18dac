"""The refined-cell benchmark (``benchmarks/refined.py``, issue 21) compares like with like: a
weakly or strongly refined beam and the layerwise beam it is timed against hold the same nodes
and, given the same displacement field, the same forces and stored energy."""

import numpy as np
import pytest
from helpers import load_benchmark
from mpi4py import MPI

from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.simulation import build_structure

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial benchmark helpers")


def nodal_forces(structure) -> np.ndarray:
    """(n, 6): each owned node's position and internal force, base and extra nodes, sorted by
    position (the two nodes of a strong interface, at one place, by their force)."""
    structure.internal_force()
    rows = []
    for X, f in (
        (structure.X_base, structure.lumped.f_base.array),
        (structure.extra.vectors["X"].array, structure.lumped.f_extra.array),
    ):
        X, f = X.reshape(-1, 3), f.reshape(-1, 3)
        n = len(f)  # the force vectors' owned and ghost entries: serial, all owned
        rows.append(np.hstack([X[:n], f]))
    table = np.vstack(rows)
    f = table[:, 3:] / np.abs(table[:, 3:]).max()
    keys = np.hstack([np.round(f[:, ::-1], 6), np.round(table[:, 2::-1], 9)])
    return table[np.lexsort(keys.T)]


@pytest.mark.parametrize("pattern", ["weak", "strong"])
def test_a_refined_beam_and_its_layerwise_beam_hold_the_same_forces(pattern):
    run = load_benchmark("run")
    refined = load_benchmark("refined")
    adaptive, layerwise = (
        build_structure(parse_config(data))
        for data in refined.pair_configs(run.beam_config(12), pattern)
    )
    refined.refine_every_cell(adaptive, pattern)
    energies, tables = [], []
    for structure in (adaptive, layerwise):
        refined.impose_field(structure)
        tables.append(nodal_forces(structure))
        energies.append(sum(structure.internal_forces.energies()))
    assert energies[0] > 1e-6  # the field strains every element (mJ)
    assert energies[0] == pytest.approx(energies[1], rel=1e-10)
    assert tables[0].shape == tables[1].shape  # the same nodes
    np.testing.assert_allclose(tables[0][:, :3], tables[1][:, :3], atol=1e-12)
    scale = np.abs(tables[1][:, 3:]).max()
    np.testing.assert_allclose(tables[0][:, 3:], tables[1][:, 3:], atol=1e-9 * scale)
