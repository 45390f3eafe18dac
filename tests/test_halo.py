"""The halo exchange of the explicit step (``parallel.Halo``): the same values as DOLFINx's
scatters, both blocks in one message, a pending reduction completed in its wait; one BLAS
thread per rank under MPI; and the synchronisation points of a step counted in MPI itself
(``benchmarks/sync_points.py``: at most the halo exchange and the reverse exchange per step
that writes no output, whatever the model)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import sync_points  # noqa: E402  (the cases, and those that wait more)

MPIEXEC = Path(sys.executable).parent / "mpiexec"
ENV = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
TIMEOUT = 300  # s, on this shared machine


@pytest.mark.parametrize("ranks", [1, 2, 3])
def test_halo_moves_what_dolfinx_scatters_move(ranks):
    """Three index maps of a box (block sizes 3 and 1), then a map without ghosts beside a
    layered strip of two columns: forward and reverse bit for bit DOLFINx's scatters, a
    reduction completed in the exchange's wait, a second start refused."""
    command = [sys.executable, str(ROOT / "tests" / "halo_case.py")]
    if ranks > 1:
        command = [str(MPIEXEC), "-n", str(ranks), *command]
    done = subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    for rank in out["ranks"]:
        # bit for bit: the same values, summed in the same order
        assert rank["forward"] == 0.0 and rank["reverse"] == 0.0
        assert rank["refused"]
        assert rank["limited"] == (ranks > 1)
        if ranks > 1:
            assert all(n == 1 for n in rank["threads"])
    if ranks > 1:
        assert out["ghosts"] == out["expected_ghosts"] and sum(out["ghosts"]) > 0
    # three ranks on two columns: one rank holds nothing and still takes part
    assert any(rank["empty_rank"] for rank in out["ranks"]) == (ranks == 3)


@pytest.mark.skipif(shutil.which("cc") is None, reason="the MPI call counter needs a C compiler")
def test_a_step_waits_twice_on_two_ranks(tmp_path):
    """Every MPI call counted (a PMPI interposer): a step that writes no history row, evaluates
    no indicator and refines nothing waits at most twice (the displacements' halo, the forces'
    reverse exchange), polls included, for ESL, adaptive (refined across the ranks, border
    constraints), layerwise with cohesive elements, a free impactor and the MMB's lever (its
    hinge's displacement and its saddle's force summed inside the two exchanges)."""
    command = [sys.executable, str(ROOT / "benchmarks" / "sync_points.py"), "--ranks", "2",
               "--steps", "140", "--out", str(tmp_path)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, env=ENV, timeout=2 * TIMEOUT)
    assert done.returncode == 0, done.stderr[-3000:]
    cases = json.loads((tmp_path / "sync_points.json").read_text())["cases"]
    assert len(cases) == 7
    for name, kinds in cases.items():
        waits = sync_points.MORE_WAITS.get(name, 2)
        assert kinds["plain"]["steps"] > 50, name
        assert kinds["plain"]["max"] == waits, (name, kinds["plain"])
        assert kinds["poll"]["max"] == waits, (name, kinds["poll"])
        # a history row: one reduction of all its sums (a free body's force waits for its own
        # reduction before the row reads it)
        if "history" in kinds:  # (a case may write no row in the steps counted)
            assert kinds["history"]["max"] <= waits + 2, (name, kinds["history"])
        # the two waits are the neighbourhood exchanges (the poll's reduction, a free body's
        # force complete inside them)
        calls = kinds["plain"]["calls_per_step"]
        assert calls.get("Waitall", 0) == waits and not calls.get("Allreduce_c"), (name, calls)
    assert sum("history" in kinds for kinds in cases.values()) >= 4
    assert set(sync_points.MORE_WAITS) <= set(cases)
