"""The scaling model of an explicit step on many ranks (``parallel.scaling``): its halo part
against the ghost nodes of real partitions (DOLFINx's of single-layer plates, the columnar
partitioner's of layered ones) on 2, 4 and 8 ranks, the grid partition of the columns, and the
model's limits (one rank: no communication; a balanced partition: the compute divides by the
ranks; a centred refined disc: the work of the patches that cover it)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fenics_adaptive.meshes.beam import grid_parts, patch_grid

from fenics_adaptive.parallel.scaling import (
    Interconnect,
    StepConstants,
    disc_work,
    ghost_nodes,
    step_time,
)

ROOT = Path(__file__).parent.parent
MPIEXEC = Path(sys.executable).parent / "mpiexec"
ENV = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


@pytest.mark.parametrize("ranks", [2, 4, 8])
def test_the_halo_model_counts_the_ghosts_of_real_partitions(ranks):
    """Mean ghost nodes per rank within 10 % of the model, the largest within 35 % (DOLFINx's
    graph partitioner cuts ragged borders; 8 ranks run oversubscribed: counts, not times)."""
    command = [str(MPIEXEC), "-n", str(ranks), sys.executable, str(ROOT / "tests/ghost_case.py")]
    done = subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    for case in json.loads(done.stdout.strip().splitlines()[-1]):
        mean, largest = ghost_nodes(case["nx"], case["ny"], ranks, case["layers"])
        ghosts = np.array(case["ghosts"])
        assert len(ghosts) == ranks
        assert abs(ghosts.mean() / mean - 1.0) < 0.10, (case, mean)
        assert abs(ghosts.max() / largest - 1.0) < 0.35, (case, largest)


def test_the_columns_are_cut_into_balanced_near_square_patches():
    ix, iy = np.meshgrid(np.arange(60), np.arange(30), indexing="ij")
    columns = np.stack([ix.ravel(), iy.ravel()], axis=1)
    for parts in (1, 2, 3, 4, 6, 8, 12):
        part = grid_parts(columns, parts)
        counts = np.bincount(part, minlength=parts)
        assert len(counts) == parts and counts.max() - counts.min() <= 2, (parts, counts)
        p, q = patch_grid(parts)
        assert p * q == parts and p <= q
        for k in range(parts):  # each patch a rectangle of columns
            mine = columns[part == k]
            box = np.ptp(mine, axis=0) + 1
            assert box.prod() <= len(mine) + box.max(), (parts, k)
    assert patch_grid(7) == (1, 7) and patch_grid(16) == (4, 4)
    # a long beam is cut into strips (shorter cuts than patches), a plate into patches
    assert patch_grid(4, 150, 20) == (4, 1) and patch_grid(8, 150, 20) == (8, 1)
    assert patch_grid(8, 300, 100) == (4, 2) and patch_grid(64, 100, 100) == (8, 8)
    with pytest.raises(ValueError):
        patch_grid(0)


def test_the_model_in_its_limits():
    constants = StepConstants(cell_step=1e-6, refined_cost=7.0, exchange_overhead=1e-5)
    network = Interconnect()
    one = step_time(constants, network, 100, 100, 1)
    assert one["total"] == pytest.approx(1e-6 * 100 * 100)
    assert one["latency"] == one["transfer"] == one["output"] == 0.0
    # unrefined: every patch has the same cells, the compute divides exactly
    for ranks in (4, 16, 64):
        parts = step_time(constants, network, 128, 128, ranks)
        assert parts["compute"] == pytest.approx(1e-6 * 128 * 128 / ranks)
        assert parts["total"] > parts["compute"]
    # a refined disc: the mean work is the plate's; on a 2 x 2 grid the centred disc splits
    # evenly, on 4 x 4 the four inner patches carry it
    for ranks in (4, 16):
        mean, largest = disc_work(200, 200, ranks, 0.1, 7.0)
        refined = np.count_nonzero(
            np.add.outer(((np.arange(200) + 0.5) / 200 - 0.5) ** 2,
                         ((np.arange(200) + 0.5) / 200 - 0.5) ** 2) <= 0.1 / np.pi
        )  # fmt: skip
        assert mean * ranks == pytest.approx(200 * 200 + 6.0 * refined)
        assert (
            largest / mean == pytest.approx(1.0, abs=1e-2) if ranks == 4 else largest > 1.5 * mean
        )
    balanced = step_time(constants, network, 200, 200, 16, 0.1, balanced=True)
    unbalanced = step_time(constants, network, 200, 200, 16, 0.1)
    assert unbalanced["compute"] > 1.5 * balanced["compute"]
    # the halo of an inner patch grows with its perimeter: the same cells per rank, the same
    # halo, on 16 or 64 ranks; four times the cells per rank, twice the halo
    assert ghost_nodes(400, 400, 16, 2)[1] == pytest.approx(ghost_nodes(800, 800, 64, 2)[1])
    assert ghost_nodes(800, 800, 16, 2)[1] == pytest.approx(
        2 * ghost_nodes(400, 400, 16, 2)[1], rel=0.01
    )


def test_the_overlap_hides_the_displacements_exchange_up_to_the_interior_work():
    constants = StepConstants(cell_step=1e-6, refined_cost=7.0, exchange_overhead=1e-5)
    network = Interconnect()
    on = step_time(constants, network, 128, 128, 16)
    off = step_time(constants, network, 128, 128, 16, overlap=False)
    # one of the two exchanges travels behind the work: its messages' latency and transfer
    in_flight = 8 * network.latency + off["transfer"] / 2  # an inner patch: eight neighbours
    assert on["hidden"] == pytest.approx(in_flight)
    assert off["total"] - on["total"] == pytest.approx(in_flight)
    assert on["latency"] == off["latency"]  # packing, unpacking, the calls: not hidden
    # a network slower than the work: at most the interior cells' compute is hidden
    slow = step_time(constants, Interconnect(latency=1.0), 128, 128, 16)
    assert 0.9 * slow["compute"] < slow["hidden"] < slow["compute"]
    assert step_time(constants, network, 128, 128, 1)["hidden"] == 0.0


def test_weighted_patches_hold_equal_cost_to_within_a_column():
    """A plate of 40 x 12 columns whose left quarter costs 3.3 each (refined at one
    interface from the start: ``parallel.balance.cell_costs``): every patch of the grid gets
    the same cost to within two of the costliest columns per level of cuts (slabs, then
    patches), the unweighted grid the same columns and unequal costs."""
    from fenics_adaptive.parallel.balance import cell_costs

    columns = np.array([(i, j) for i in range(40) for j in range(12)])
    weights = cell_costs(np.where(columns[:, 0] < 10, 1, 0))
    assert weights.max() == pytest.approx(3.3)
    for parts in (2, 3, 4, 6, 8):
        part = grid_parts(columns, parts, weights)
        cost = np.bincount(part, weights=weights, minlength=parts)
        a, b = patch_grid(parts, 40, 12)
        levels = (a > 1) + (b > 1)  # a part's two cuts: each off by up to half a column
        assert np.ptp(cost) <= 2 * levels * weights.max() + 1e-9, (parts, cost)
        equal = grid_parts(columns, parts)
        assert np.ptp(np.bincount(equal, minlength=parts)) <= 1
        assert np.ptp(np.bincount(equal, weights=weights)) > 10 * weights.max()
    with pytest.raises(ValueError):
        grid_parts(columns, 2, np.zeros(len(columns)))
    with pytest.raises(ValueError):
        grid_parts(columns, 2, weights[:-1])
