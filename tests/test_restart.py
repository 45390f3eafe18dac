"""Checkpoint and restart: a resumed run repeats the uninterrupted one to round-off, with the
refinement states, ply and cohesive damage, tie forces and damping windows of the moment it
stopped; SIGTERM leaves a checkpoint, a flushed partial history and a summary that says so.
Chains of restarts (extension, interrupted extension, repeated restarts) give the
uninterrupted history row for row; a kill at any point of the checkpoint write leaves one
complete checkpoint; a damaged checkpoint is refused with one line naming the file."""

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
from helpers import assert_restarted_history, late_refinement_toml, run_quietly
from mpi4py import MPI

from fenics_adaptive import runner
from fenics_adaptive.errors import InputError
from fenics_adaptive.io import checkpoint
from fenics_adaptive.io.output import read_history
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.solver.explicit import Interrupted

DATA = Path(__file__).parent / "data"


def late_refinement(end_time: float, checkpoint_interval: int | None = None) -> dict:
    return tomllib.loads(late_refinement_toml(end_time, checkpoint_interval))


@pytest.mark.slow
def test_resumed_history_equals_the_uninterrupted_one(tmp_path):
    run_quietly(late_refinement(1.0e-4), tmp_path / "whole")
    first = run_quietly(late_refinement(6.0e-5, checkpoint_interval=400), tmp_path / "split")
    assert (tmp_path / "split" / "checkpoint" / "checkpoint.json").exists()
    summary = run_quietly(late_refinement(1.0e-4), tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole")
    whole = read_history(tmp_path / "whole" / "history.csv")
    # the refinement log goes on from the checkpoint's as if never interrupted
    log = "refinement_log.csv"
    assert (tmp_path / "split" / log).read_text() == (tmp_path / "whole" / log).read_text()
    # the split really crossed open stabilisation windows and a refined, damaged structure
    assert first["refinement_events"] == 2
    assert summary["cohesive_elements_at_end"] > 0
    assert max(whole["damping_energy"]) > 0.0


def opening_tcb(end_time: float, checkpoint_interval: int | None = None) -> dict:
    """The TCB's arms pulled open, refined by the interface-stress indicator alone with its
    look-ahead over a release window of 1e-5 s (its lead 1.1e-5 s)."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    del data["interfaces"]["initial"]
    data["indicators"] = {"interval": 1.0e-6, "interface_stress": 0.5, "front_distance": 0.0}
    data["stabilisation"] = {"release_window": 1.0e-5}
    data["solver"]["end_time"] = end_time
    data["output"].pop("fields_interval", None)
    if checkpoint_interval is not None:
        data["output"]["checkpoint_interval"] = checkpoint_interval
    return data


@pytest.mark.slow
def test_a_restart_keeps_the_look_ahead_s_past_indices(tmp_path):
    """Split where the look-ahead has a lead's worth of past indices, the restarted run
    predicts from the checkpoint's and refines the same cells at the same steps: history and
    refinement log as the uninterrupted run's."""
    run_quietly(opening_tcb(4.0e-5), tmp_path / "whole")
    run_quietly(opening_tcb(2.5e-5, checkpoint_interval=100), tmp_path / "split")
    run_quietly(opening_tcb(4.0e-5), tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole")
    log = (tmp_path / "whole" / "refinement_log.csv").read_text()
    assert (tmp_path / "split" / "refinement_log.csv").read_text() == log
    # the prediction flagged cells of its own within a lead after the split, from indices
    # the checkpoint held
    rows = [line.split(",") for line in log.splitlines()[1:]]
    assert any(r[6] == "look_ahead" and 2.5e-5 < float(r[0]) <= 3.6e-5 for r in rows)


@pytest.mark.slow
def test_restart_refuses_another_model_or_rank_count(tmp_path):
    run_quietly(late_refinement(2.0e-5, checkpoint_interval=1000), tmp_path / "a")
    other = late_refinement(4.0e-5)
    other["cohesive"]["GIc"] = 0.5
    with pytest.raises(InputError, match="config differs"):
        run_quietly(other, tmp_path / "a", restart=tmp_path / "a")
    with pytest.raises(InputError, match="no complete checkpoint"):
        run_quietly(late_refinement(4.0e-5), tmp_path / "b", restart=tmp_path / "nothing")


@pytest.mark.slow
def test_sigterm_on_an_extension_and_the_printed_restart_command(tmp_path):
    """The reported chain, with real signals and a path with a space: a finished run is
    extended with --restart, the extension is stopped by SIGTERM (exit status 130, a
    checkpoint, a partial history, an "interrupted" summary), and the shell-quoted command it
    prints continues it: the history is the uninterrupted one row for row."""
    config = tmp_path / "my case" / "run.toml"
    config.parent.mkdir()
    out = tmp_path / "out dir"
    run_quietly(late_refinement(4.0e-5, checkpoint_interval=1000), out)
    finished = read_history(out / "history.csv")
    config.write_text(late_refinement_toml(1.2e-3))
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parent.parent))
    extend = [*CLI, "run", str(config), "--out", str(out), "--restart", str(out), "--quiet"]
    process = subprocess.Popen(extend, env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while (
        not (out / "history.partial.csv").exists()
        or len((out / "history.partial.csv").read_text().splitlines()) < 300
    ):
        assert process.poll() is None and time.time() < deadline
        time.sleep(0.2)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert (out / "checkpoint" / "checkpoint.json").exists()
    # the finished run's history stays as it was; the extension's is partial
    assert read_history(out / "history.csv") == finished
    partial = read_history(out / "history.partial.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    stopped = float(json.loads((out / "checkpoint" / "checkpoint.json").read_text())["time_s"])
    assert finished["time"][-1] < stopped and partial["time"][-1] <= stopped
    hint = shlex.split(stderr.strip().splitlines()[-1].split("continue with: ")[1])
    assert hint == ["fenics-adaptive", "run", str(config), "--out", str(out), "--restart", str(out)]
    # finish it with the printed command (a shorter end time), and the same run uninterrupted
    short_end = min(1.2e-3, stopped + 2.0e-5)
    config.write_text(late_refinement_toml(short_end))
    done = subprocess.run([*CLI, *hint[1:], "--quiet"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    run_quietly(late_refinement(short_end), tmp_path / "whole")
    assert_restarted_history(out, tmp_path / "whole")


CLI = [sys.executable, "-m", "fenics_adaptive"]


# ------------------------------------------------------------------ chains, deterministically
def tcb(end_time: float, checkpoint_interval: int | None = None) -> dict:
    """The refined TCB beam (cohesive elements from the start), time step 4e-8 s: 2500 steps
    to 1e-4 s, a history row every 2e-6 s."""
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["solver"]["end_time"] = end_time
    if checkpoint_interval is not None:
        data["output"]["checkpoint_interval"] = checkpoint_interval
    return data


def stop_at_poll(monkeypatch, poll: int | None) -> None:
    """Make the run stop (as on SIGTERM) at its poll number ``poll`` (polls come every 64
    steps), or never (None)."""

    class Stop:
        def __init__(self, comm=None):
            self.polls = 0

        def __call__(self) -> bool:
            self.polls += 1
            return poll is not None and self.polls >= poll

        def release(self) -> None:
            pass

    monkeypatch.setattr(runner, "_StopOnSignal", Stop)


@pytest.fixture(scope="module")
def whole_tcb(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "out"
    run_quietly(tcb(1.0e-4), out)
    return out


@pytest.mark.slow
def test_extension_interrupted_extension_and_restart_again(tmp_path, monkeypatch, whole_tcb):
    """The reported bug: the second restart read the finished run's history.csv before the
    extension's history.partial.csv, and lost the rows between them."""
    out = tmp_path / "out"
    assert run_quietly(tcb(4.0e-5, checkpoint_interval=500), out)["status"] == "completed"
    stop_at_poll(monkeypatch, 5)
    with pytest.raises(Interrupted):
        run_quietly(tcb(1.0e-4), out, restart=out)
    assert (out / "history.csv").exists() and (out / "history.partial.csv").exists()
    assert read_history(out / "history.csv")["time"][-1] < 4.1e-5
    stop_at_poll(monkeypatch, None)
    assert run_quietly(tcb(1.0e-4), out, restart=out)["status"] == "completed"
    assert_restarted_history(out, whole_tcb)
    assert not (out / "history.partial.csv").exists()


@pytest.mark.slow
def test_repeated_interruptions_and_restarts(tmp_path, monkeypatch, whole_tcb):
    out = tmp_path / "out"
    times = []
    for poll in (4, 6, 3, None):
        stop_at_poll(monkeypatch, poll)
        if poll is None:
            run_quietly(tcb(1.0e-4), out, restart=out if times else None)
            break
        with pytest.raises(Interrupted) as caught:
            run_quietly(tcb(1.0e-4), out, restart=out if times else None)
        times.append(caught.value.t)
    assert len(times) == 3 and times == sorted(times)
    assert_restarted_history(out, whole_tcb)
    # one generation is left in the checkpoint folder
    names = sorted(p.name for p in (out / "checkpoint").iterdir())
    assert len(names) == 3 and names[0] == "checkpoint.json", names


@pytest.mark.slow
def test_a_restart_into_another_folder_keeps_the_checkpoint_s_history(
    tmp_path, monkeypatch, whole_tcb
):
    out = tmp_path / "out"
    stop_at_poll(monkeypatch, 7)
    with pytest.raises(Interrupted):
        run_quietly(tcb(1.0e-4), out)
    stop_at_poll(monkeypatch, None)
    run_quietly(tcb(1.0e-4), tmp_path / "elsewhere", restart=out)
    assert_restarted_history(tmp_path / "elsewhere", whole_tcb)


# ------------------------------------------------------------------ the write protocol
class Killed(BaseException):
    """A kill in the middle of the checkpoint write."""


def small(end_time: float = 2.0e-4, checkpoint_interval: int | None = 500) -> dict:
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["solver"]["end_time"] = end_time
    if checkpoint_interval is not None:
        data["output"]["checkpoint_interval"] = checkpoint_interval
    return data


@pytest.fixture(scope="module")
def whole_small(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole_small") / "out"
    run_quietly(small(checkpoint_interval=None), out)
    return out


@pytest.mark.slow
@pytest.mark.parametrize(
    "point, step",
    [
        ("rank file half written", 500),
        ("history file half written", 500),
        ("checkpoint.json.partial half written", 500),
        ("before the commit", 500),
        ("after the commit, before the old files go", 1000),
    ],
)
def test_a_kill_at_any_point_of_the_write_leaves_one_complete_checkpoint(
    tmp_path, monkeypatch, whole_small, point, step
):
    """The second checkpoint (step 1000) is killed at each point of its write: the folder
    then holds the first (step 500) or the second, complete, and the restart from it gives the
    uninterrupted history."""
    writes = []
    original_write = checkpoint.write_durably
    torn = {  # the file the kill tears, by the start of its name
        "rank file half written": "rank",
        "history file half written": "history-",
        "checkpoint.json.partial half written": "checkpoint.json.partial",
    }.get(point)

    def write(path, data):
        writes.append(path.name)
        second = len(writes) > 3  # the first checkpoint writes three files
        if second and torn is not None and path.name.startswith(torn):
            path.write_bytes(data[: len(data) // 2])
            raise Killed
        original_write(path, data)

    def commit(partial, final):
        if point == "before the commit" and len(writes) > 3:
            raise Killed
        original_commit(partial, final)

    def remove(folder, sequence):
        if point.startswith("after the commit") and len(writes) > 3:
            raise Killed
        return original_remove(folder, sequence)

    original_commit, original_remove = checkpoint.commit, checkpoint.remove_superseded
    monkeypatch.setattr(checkpoint, "write_durably", write)
    monkeypatch.setattr(checkpoint, "commit", commit)
    monkeypatch.setattr(checkpoint, "remove_superseded", remove)
    out = tmp_path / "out"
    with pytest.raises(Killed):
        run_quietly(small(), out)
    monkeypatch.undo()
    assert len(writes) >= 4
    manifest, _, _ = checkpoint.read(out, MPI.COMM_WORLD, parse_config(small()))
    assert manifest["step"] == step
    run_quietly(small(checkpoint_interval=None), out, restart=out)
    assert_restarted_history(out, whole_small)


@pytest.mark.slow
def test_checkpoints_of_the_earlier_format_are_found(tmp_path, monkeypatch, whole_small):
    """The earlier version's kill between its two renames left checkpoint.old/ and
    checkpoint.partial/ (the newer), both complete, and no checkpoint/: the newer is used."""
    out = tmp_path / "out"
    stop_at_poll(monkeypatch, 12)
    with pytest.raises(Interrupted):
        run_quietly(small(checkpoint_interval=None), out)
    stop_at_poll(monkeypatch, None)
    folder = out / "checkpoint"
    manifest = json.loads((folder / "checkpoint.json").read_text())
    legacy = {k: manifest[k] for k in ("time_s", "step", "mpi_ranks", "config_fingerprint")}
    legacy["config"] = manifest["config"]
    for name, ranks in (("checkpoint.partial", 1), ("checkpoint.old", 2)):
        (out / name).mkdir()
        (folder / manifest["ranks"][0]["name"]).rename(out / name / "rank0.npz")
        (out / name / "checkpoint.json").write_text(json.dumps({**legacy, "mpi_ranks": ranks}))
        if ranks == 1:
            shutil.copy(out / name / "rank0.npz", folder / manifest["ranks"][0]["name"])
    shutil.rmtree(folder)
    run_quietly(small(checkpoint_interval=None), out, restart=out)
    assert_restarted_history(out, whole_small)


# ------------------------------------------------------------------ damaged checkpoints
@pytest.fixture(scope="module")
def finished_small(tmp_path_factory):
    out = tmp_path_factory.mktemp("finished") / "out"
    run_quietly(small(checkpoint_interval=1000), out)
    return out


def damage(folder: Path, how: str) -> str:
    """Damage the checkpoint in ``folder`` one way; returns the name of the damaged file."""
    checkpoint_dir = folder / "checkpoint"
    manifest = json.loads((checkpoint_dir / "checkpoint.json").read_text())
    rank_file = checkpoint_dir / manifest["ranks"][0]["name"]
    history_file = checkpoint_dir / manifest["history"]["name"]
    if how == "truncated npz":
        rank_file.write_bytes(rank_file.read_bytes()[:1000])
        return rank_file.name
    if how == "altered npz":
        data = bytearray(rank_file.read_bytes())
        data[len(data) // 2] ^= 0xFF
        rank_file.write_bytes(bytes(data))
        return rank_file.name
    if how == "missing rank file":
        rank_file.unlink()
        return rank_file.name
    if how == "missing history":
        history_file.unlink()
        return history_file.name
    if how == "corrupt json":
        (checkpoint_dir / "checkpoint.json").write_text('{"time_s": 1.0, "st')
        return "checkpoint.json"
    if how == "json without step":
        del manifest["step"]
        (checkpoint_dir / "checkpoint.json").write_text(json.dumps(manifest))
        return "checkpoint.json"
    if how in ("json time NaN", "json time not the files'"):
        manifest["time_s"] = float("nan") if how == "json time NaN" else 0.5 * manifest["time_s"]
        (checkpoint_dir / "checkpoint.json").write_text(json.dumps(manifest))
        return "checkpoint.json"
    if how == "truncated npz, earlier format":
        legacy = checkpoint_dir / "rank0.npz"
        legacy.write_bytes(rank_file.read_bytes()[:1000])
        rank_file.unlink()
        (checkpoint_dir / "checkpoint.json").write_text(
            json.dumps({k: v for k, v in manifest.items() if k not in ("ranks", "history")})
        )
        return legacy.name
    raise AssertionError(how)


@pytest.mark.slow
@pytest.mark.parametrize(
    "how",
    [
        "truncated npz",
        "altered npz",
        "missing rank file",
        "missing history",
        "corrupt json",
        "json without step",
        "json time NaN",
        "json time not the files'",
        "truncated npz, earlier format",
    ],
)
def test_a_damaged_checkpoint_is_refused_naming_the_file(tmp_path, finished_small, how):
    out = tmp_path / "out"
    shutil.copytree(finished_small, out)
    name = damage(out, how)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(InputError) as caught:
        run_quietly(small(end_time=3.0e-4), out, restart=out)
    assert caught.value.key == "restart"
    assert name in str(caught.value), str(caught.value)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


@pytest.mark.slow
def test_a_restart_that_would_end_before_its_checkpoint_is_refused(tmp_path, finished_small):
    """An end time before the checkpoint's: refused, nothing written (it would have run no
    step and called the run completed past its end)."""
    out = tmp_path / "out"
    shutil.copytree(finished_small, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    t = json.loads((out / "checkpoint" / "checkpoint.json").read_text())["time_s"]
    with pytest.raises(InputError) as caught:
        run_quietly(small(end_time=0.5 * t), out, restart=out)
    assert caught.value.key == "solver.end_time" and "before the checkpoint" in str(caught.value)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


@pytest.mark.slow
def test_cli_refuses_a_damaged_checkpoint_with_one_line(tmp_path, finished_small):
    out = tmp_path / "out"
    shutil.copytree(finished_small, out)
    name = damage(out, "truncated npz")
    config = tmp_path / "longer.toml"
    text = (DATA / "small_beam.toml").read_text()
    config.write_text(text.replace("end_time = 2.0e-4", "end_time = 3.0e-4"))
    result = subprocess.run(
        [*CLI, "run", str(config), "--out", str(out), "--restart", str(out)],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(Path(__file__).parent.parent)),
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and name in lines[0] and "restart" in lines[0], lines
    assert "Traceback" not in result.stderr
