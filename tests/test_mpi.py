"""MPI: the same run on 1 and 2 ranks gives the same history (up to summation order)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.output import read_history

SMALL = Path(__file__).parent / "data" / "small_beam.toml"
MPIEXEC = Path(sys.executable).parent / "mpiexec"


def run(out: Path, ranks: int) -> dict:
    command = [sys.executable, "-m", "fenics_adaptive", "run", str(SMALL), "--out", str(out)]
    if ranks > 1:
        command = [str(MPIEXEC), "-n", str(ranks), *command]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return read_history(out / "history.csv")


@pytest.mark.mpi
def test_two_ranks_reproduce_the_serial_history(tmp_path):
    serial = run(tmp_path / "serial", 1)
    parallel = run(tmp_path / "parallel", 2)
    assert serial["time"] == parallel["time"]
    assert serial["time_step"] == parallel["time_step"]
    for column in ("reaction_force", "displacement", "internal_energy", "kinetic_energy"):
        a, b = np.array(serial[column]), np.array(parallel[column])
        scale = np.abs(a).max()
        assert scale > 0, column
        assert np.abs(a - b).max() <= 1e-10 * scale, column
