"""Re-balancing and restart on another partition (issue 23): a checkpoint's arrays say how
their rows are indexed, so that a run continues on another number of ranks, or on a partition
cut again by the refinement's cost, with the history of the uninterrupted serial run; an
adaptive run whose refinement unbalances the ranks re-balances itself once a refinement's
ties and damping windows are over; a checkpoint that cannot move says so.

Every program runs under a timeout: a deadlock fails the test instead of hanging the suite.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_same_history, edited, late_refinement_toml

from fenics_adaptive.io.output import read_history
from fenics_adaptive.parallel import redistribute
from fenics_adaptive.parallel.balance import cell_costs, refined_cost

ROOT = Path(__file__).parent.parent
DATA = Path(__file__).parent / "data"
MPIEXEC = Path(sys.executable).parent / "mpiexec"
TIMEOUT = 240  # s, for one program on this (shared, loaded) machine
ENV = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


def run(config: Path, out: Path, ranks: int, restart: Path | None = None) -> dict:
    """``fenics-adaptive run`` on ``ranks`` ranks; returns the summary. Fails with the run's
    own message."""
    command = [sys.executable, "-m", "fenics_adaptive", "run", str(config), "--out", str(out)]
    command += ["--restart", str(restart)] if restart else ["--overwrite"]
    if ranks > 1:
        command = [str(MPIEXEC), "-n", str(ranks), *command]
    result = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT, env=ENV)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    return json.loads((out / "summary.json").read_text())


def late_refinement(tmp_path: Path, end_time: float, checkpoint: bool = False) -> Path:
    """``helpers.late_refinement_toml`` (history rows every 2e-6 s; a checkpoint at the end
    only) as a file: on two ranks (a strip each) its refinement lands on one of them."""
    text = late_refinement_toml(end_time, 1000000 if checkpoint else None, history_interval=None)
    path = tmp_path / f"late_{end_time:.0e}{'_checkpoint' if checkpoint else ''}.toml"
    path.write_text(text)
    return path


def quick_dcb(tmp_path: Path, end_time: float) -> Path:
    """The quick DCB of tests/data/mpi_front_across_ranks.toml (an insert film, [indicators]
    at their defaults, the front refining across the ranks) cut by cost, to ``end_time``,
    with a checkpoint at its end."""
    text = edited(
        DATA / "mpi_front_across_ranks.toml",
        (
            ('partition = "cells"', ""),
            ("end_time = 1.6e-3", f"end_time = {end_time!r}"),
            ("[output]", "[output]\ncheckpoint_interval = 1000000"),
        ),
    )
    path = tmp_path / f"dcb_{end_time:.0e}.toml"
    path.write_text(text)
    return path


def test_rows_reach_any_partition():
    """Arrays written by two ranks (owned rows, a ghost copy, a partial sum, a replicated
    value, rows along axis 1) read on three: every row from the rank that owned its key, the
    sums kept, a missing row refused unless it has a fill."""
    old = [
        {"u": np.array([1.0, 2.0, 30.0]), "w": np.array(1.5), "t": np.array(7.0),
         "snap": np.array([[10.0, 20.0]])},
        {"u": np.array([3.0, 4.0]), "w": np.array(2.5), "t": np.array(7.0),
         "snap": np.array([[30.0, 40.0]])},
    ]  # fmt: skip
    layouts = [
        {"u": redistribute.Rows(np.array([10, 11, 12]), np.array([True, True, False])),
         "w": redistribute.PARTIAL, "snap": redistribute.Rows(np.array([5, 6]), axis=1)},
        {"u": redistribute.Rows(np.array([12, 13])), "w": redistribute.PARTIAL,
         "snap": redistribute.Rows(np.array([7, 8]), axis=1)},
    ]  # fmt: skip
    files = [redistribute.annotate(a, lay) for a, lay in zip(old, layouts, strict=True)]
    new = [redistribute.StoredState(files, rank, 3) for rank in range(3)]
    # the ghost copy (30.0) of key 12 is not read: the owner's 3.0 is
    rows = redistribute.Rows(np.array([13, 12, 10]))
    np.testing.assert_array_equal(new[0].value("u", rows), [4.0, 3.0, 1.0])
    np.testing.assert_array_equal(
        new[2].value("snap", redistribute.Rows(np.array([8, 5]), axis=1)), [[40.0, 10.0]]
    )
    shares = [float(state.value("w")) for state in new]
    assert shares == [1.5, 2.5, 0.0]  # old rank r's share on new rank r mod 3: total kept
    assert float(new[1].value("t")) == 7.0
    with pytest.raises(KeyError):
        new[0].value("u", redistribute.Rows(np.array([10, 99])))
    filled = new[0].value("u", redistribute.Rows(np.array([99, 11]), fill=-1.0))
    np.testing.assert_array_equal(filled, [-1.0, 2.0])


def test_refined_cost_weighs_the_refined_cells():
    """A re-balanced partition weighs each cell as refined at the checkpoint: found by its
    centroid, 1 + 2.3 per interface; an unrefined cell 1."""
    cost = refined_cost(np.array([[0.25, 0.25], [1.75, 0.25]]), np.array([3, 1]), 0.5)
    x, y = np.array([0.25, 0.75, 1.75]), np.array([0.25, 0.25, 0.25])
    np.testing.assert_allclose(cost(x, y), cell_costs(np.array([3, 0, 1])))


@pytest.fixture(scope="module")
def late_on_two(tmp_path_factory) -> tuple[Path, dict]:
    """The late refinement to 1e-4 s on two ranks, a checkpoint at its end: (its folder, its
    summary)."""
    folder = tmp_path_factory.mktemp("late")
    summary = run(late_refinement(folder, 1.0e-4, checkpoint=True), folder / "two", 2)
    return folder / "two", summary


@pytest.mark.mpi
def test_refinement_on_one_rank_rebalances_the_run(tmp_path, late_on_two):
    """On two ranks the refinement of the beam's half makes one rank 1.78 x the mean; the run
    re-balances once its ties and damping windows are over (7.2e-5 s) to within a cell of
    equal cost, and its history is the serial one."""
    run(late_refinement(tmp_path, 1.0e-4, checkpoint=True), tmp_path / "serial", 1)
    two, summary = late_on_two
    (event,) = summary["load_balance"]["rebalanced"]
    assert event["imbalance_before"] > 1.7
    # the windows close at 2e-5 + 5e-5 s: the first history row after it
    assert 7.0e-5 <= event["time_s"] <= 7.4e-5
    assert event["imbalance_after"] < 1.1
    assert_same_history(read_history(tmp_path / "serial" / "history.csv"),
                        read_history(two / "history.csv"))  # fmt: skip


@pytest.mark.mpi
def test_restart_after_a_rebalance_repeats_the_run(tmp_path, late_on_two):
    """A checkpoint taken after a re-balance continues on as many ranks on the same cut (the
    refinement of the re-balance's time, from the log), bit for bit."""
    whole, _ = late_on_two
    split = tmp_path / "split"
    run(late_refinement(tmp_path, 8.0e-5, checkpoint=True), split, 2)
    manifest = json.loads((split / "checkpoint" / "checkpoint.json").read_text())
    assert manifest["partition"]["weights"] == "refinement" and manifest["movable"]
    run(late_refinement(tmp_path, 1.0e-4, checkpoint=True), split, 2, restart=split)
    resumed, expected = (read_history(p / "history.csv") for p in (split, whole))
    for name, values in expected.items():
        np.testing.assert_array_equal(resumed[name], values, err_msg=name)


@pytest.mark.mpi
def test_checkpoint_continues_on_other_rank_counts(tmp_path):
    """The quick DCB written by two ranks half-way (film, front, refinement of the front on
    both) continues on one and on three ranks with the serial run's history."""
    serial = tmp_path / "serial"
    run(quick_dcb(tmp_path, 6.0e-4), serial, 1)
    expected = read_history(serial / "history.csv")
    written = tmp_path / "written"
    run(quick_dcb(tmp_path, 3.0e-4), written, 2)
    for ranks in (1, 3):
        out = tmp_path / f"two_then_{ranks}"
        shutil.copytree(written, out)
        run(quick_dcb(tmp_path, 6.0e-4), out, ranks, restart=out)
        assert_same_history(expected, read_history(out / "history.csv"))


@pytest.mark.mpi
def test_checkpoint_with_active_ties_stays_on_its_ranks(tmp_path, late_on_two):
    """A checkpoint written while a refinement's ties act cannot move (the ties are pairs of
    extra nodes in flight): another rank count is refused with a message that says so. On
    as many ranks it continues, and the re-balance that was waiting for the windows to close
    when it was written (the refinement made one rank 1.78 x the mean) is made when they
    close, as in the run that was not stopped: the same history, bit for bit."""
    out = tmp_path / "ties"
    run(late_refinement(tmp_path, 5.0e-5, checkpoint=True), out, 2)
    manifest = json.loads((out / "checkpoint" / "checkpoint.json").read_text())
    assert not manifest["movable"]
    command = [sys.executable, "-m", "fenics_adaptive", "run",
               str(late_refinement(tmp_path, 1.0e-4, checkpoint=True)), "--out", str(out),
               "--restart", str(out)]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT, env=ENV)
    assert result.returncode != 0
    message = result.stdout + result.stderr
    assert "cannot move to another partition" in message and "restart it on as many" in message
    assert "Traceback" not in message
    whole, uninterrupted = late_on_two
    summary = run(late_refinement(tmp_path, 1.0e-4, checkpoint=True), out, 2, restart=out)
    (event,) = summary["load_balance"]["rebalanced"]
    assert event["time_s"] == uninterrupted["load_balance"]["rebalanced"][0]["time_s"]
    resumed, expected = (read_history(p / "history.csv") for p in (out, whole))
    for name, values in expected.items():
        np.testing.assert_array_equal(resumed[name], values, err_msg=name)


@pytest.mark.mpi
def test_rebalanced_refinement_on_one_rank_keeps_the_serial_history(tmp_path):
    """tests/data/mpi_one_rank_face_load.toml without its ``rebalance = 0``: the refinement
    near the clamp and under the tip load, which moves onto the extra nodes, makes one rank
    1.53 x the mean; the run re-balances once the ties let go and keeps the serial history,
    ties' work included (mpi_one_rank_refinement.toml, the same without the load, likewise:
    1.53 -> 1.02, measured once)."""
    case = "mpi_one_rank_face_load"
    config = tmp_path / f"{case}.toml"
    config.write_text(edited(DATA / f"{case}.toml", (("rebalance = 0", ""),)))
    run(config, tmp_path / "serial", 1)
    summary = run(config, tmp_path / "two", 2)
    (event,) = summary["load_balance"]["rebalanced"]
    assert event["imbalance_before"] > 1.5 > 1.1 > event["imbalance_after"]
    assert_same_history(read_history(tmp_path / "serial" / "history.csv"),
                        read_history(tmp_path / "two" / "history.csv"))  # fmt: skip


@pytest.mark.mpi
def test_a_rebalance_asked_for_at_a_refinement_waits_one_step(tmp_path):
    """The impact of tests/data/mpi_one_rank_impact.toml (ply damage, an impactor, matrix
    cracks refining next to the clamp) with ``rebalance = 1.01`` and no stabilisation: the
    re-balance is due at the refinement's own evaluation, whose new extra nodes on the
    clamped face take their prescribed values only with the next step; it waits for that
    step, and the run keeps the serial history (at the refinement itself the energy balance
    jumped by a fifth and the force by 1.5e-3): to 1e-7 of each column's scale. The matrix
    cracks carry the sums' round-off of the new partition on: 1.7e-10 when the damage law read
    the plies' mean strain, 2e-9 (displacement) to 9e-8 (reaction force) since it reads what
    each point of a ply releases (the same two ranks without a re-balance: 2e-10)."""
    config = tmp_path / "impact.toml"
    edits = (("rebalance = 0", "rebalance = 1.01"), ("end_time = 2.1e-5", "end_time = 2.4e-5"))
    config.write_text(edited(DATA / "mpi_one_rank_impact.toml", edits))
    run(config, tmp_path / "serial", 1)
    summary = run(config, tmp_path / "two", 2)
    assert summary["load_balance"]["rebalanced"]
    assert_same_history(read_history(tmp_path / "serial" / "history.csv"),
                        read_history(tmp_path / "two" / "history.csv"), rtol=1e-7)  # fmt: skip


@pytest.mark.mpi
def test_a_checkpoint_after_a_rebalance_that_cannot_move_still_restarts(tmp_path):
    """Re-balanced at 7.2e-5 s, then refined again at 8e-5 s: the checkpoint at 9e-5 s is
    taken while that refinement's ties act (it cannot move to another rank count) and
    continues on as many ranks, on the run's cut, with the uninterrupted history."""
    extra = '\n[[refinement]]\ninterfaces = [4]\nkind = "weak"\ntime = 8.0e-5\nx_max = 5.0\n'
    whole, split = tmp_path / "whole", tmp_path / "split"
    full = late_refinement(tmp_path, 1.0e-4, checkpoint=True)
    full.write_text(full.read_text() + extra)
    half = late_refinement(tmp_path, 9.0e-5, checkpoint=True)
    half.write_text(half.read_text() + extra)
    run(full, whole, 2)
    run(half, split, 2)
    manifest = json.loads((split / "checkpoint" / "checkpoint.json").read_text())
    assert manifest["partition"]["weights"] == "refinement" and not manifest["movable"]
    run(full, split, 2, restart=split)
    resumed, expected = (read_history(p / "history.csv") for p in (split, whole))
    for name, values in expected.items():
        np.testing.assert_array_equal(resumed[name], values, err_msg=name)
