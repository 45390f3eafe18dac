"""The output folder: a run deletes only what a run wrote there (its manifest), refuses a
folder of other files unless --overwrite (and even then removes only its own names), removes
nothing before the config and the model are checked, and holds a lock while it writes."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive import runner
from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.io.run_folder import LOCK, MANIFEST, RunFolder, is_own_name, read_manifest
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.solver import explicit

DATA = Path(__file__).parent / "data"
SMALL = DATA / "small_beam.toml"
ROOT = Path(__file__).parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
CLI = [sys.executable, "-m", "fenics_adaptive"]

# a user's files, among and inside the folders a run writes (the example)
USER_FILES = {
    "elements/drawing.svg": "<svg/>",
    "plies/layup.xlsx": "layup",
    "checkpoint/state.h5": "state",
    "restart_step_notes/todo.txt": "todo",
    "notes.txt": "my notes",
}


def small(**changes) -> dict:
    data = tomllib.loads(SMALL.read_text())
    data["solver"]["end_time"] = 4.0e-5
    data["output"]["fields_interval"] = 1.0e-5
    for key, value in changes.items():
        section, name = key.split("__")
        data[section][name] = value
    return data


def run(data: dict, out: Path, **kw) -> dict:
    return runner.run_config(parse_config(data), out, show_progress=False, log=None, **kw)


def put(folder: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_a_new_run_removes_what_the_last_run_wrote_and_nothing_else(tmp_path):
    out = tmp_path / "out"
    run(small(output__checkpoint_interval=200), out)
    first = snapshot(out)
    assert "elements/elements_000004.vtu" in first and "checkpoint/checkpoint.json" in first
    listed = read_manifest(out)
    files = [e for e in listed if not e.endswith("/")]
    # the manifest names every file the run left, and only names of this program
    assert sorted(set(first) - {MANIFEST}) == sorted(f for f in files if (out / f).exists())
    assert all(is_own_name(f) for f in files), files
    # the superseded checkpoint generation was removed and forgotten
    gone = [e for e in files if e.startswith("checkpoint/") and not (out / e).exists()]
    assert gone == ["checkpoint/checkpoint.json.partial"], gone
    assert json.loads((out / "checkpoint" / "checkpoint.json").read_text())["sequence"] == 2
    put(out, USER_FILES)
    # fewer field outputs this time: the earlier run's later files must go, not stay behind
    run(small(output__fields_interval=2.0e-5), out)
    after = snapshot(out)
    for name, text in USER_FILES.items():
        assert after[name] == text.encode(), name
    assert "elements/elements_000002.vtu" in after
    assert "elements/elements_000004.vtu" not in after
    assert not any(name.startswith("checkpoint/") and name != "checkpoint/state.h5"
                   for name in after)  # fmt: skip
    assert not (out / LOCK).exists()
    assert read_history(out / "history.csv")["time"][-1] == pytest.approx(4.0e-5, rel=1e-2)
    assert not any(name in USER_FILES for name in read_manifest(out))


@pytest.mark.slow
def test_a_folder_of_other_files_is_refused_and_overwrite_removes_only_own_names(tmp_path):
    out = tmp_path / "mine"
    files = {**USER_FILES, "history.csv": "my own table", "summary.json": "{}"}
    put(out, files)
    before = snapshot(out)
    with pytest.raises(InputError, match="not a fenics-adaptive run folder") as caught:
        run(small(), out)
    assert caught.value.key == "--out"
    assert snapshot(out) == before
    run(small(), out, overwrite=True)
    after = snapshot(out)
    for name, text in USER_FILES.items():
        assert after[name] == text.encode(), name
    assert read_history(out / "history.csv")["time"][0] == 0.0  # the run's own now
    assert json.loads(after["summary.json"])["status"] == "completed"


@pytest.mark.slow
def test_own_names_the_manifest_does_not_list_are_refused(tmp_path):
    out = tmp_path / "out"
    run(small(), out)
    (out / "checkpoint").mkdir()
    (out / "checkpoint" / "rank0-7.npz").write_text("not the run's")
    with pytest.raises(InputError, match="does not list"):
        run(small(), out)
    assert (out / "checkpoint" / "rank0-7.npz").exists()
    run(small(), out, overwrite=True)
    assert not (out / "checkpoint").exists()


@pytest.mark.slow
def test_nothing_is_removed_before_the_config_and_the_model_are_checked(tmp_path, monkeypatch):
    out = tmp_path / "out"
    run(small(output__checkpoint_interval=200), out)
    put(out, USER_FILES)
    before = snapshot(out)
    with pytest.raises(InputError, match=r"solver\.time_step"):  # refused while building
        run(small(solver__time_step=1e-6), out)
    assert snapshot(out) == before
    other = small()
    other["materials"]["prototype"]["E1"] = 90000.0
    with pytest.raises(InputError, match="config differs"):  # a restart of another model
        run(other, out, restart=out)
    assert snapshot(out) == before

    def fail_at_step_0(*args, **kwargs):
        raise RuntimeError("failed at step 0")

    monkeypatch.setattr(explicit.ExplicitSolver, "run", fail_at_step_0)
    with pytest.raises(RuntimeError, match="step 0"):
        run(small(), out)
    after = snapshot(out)
    for name, text in USER_FILES.items():
        assert after[name] == text.encode(), name
    assert json.loads(after["summary.json"])["status"] == "failed"
    assert "history.csv" not in after  # the earlier run's results are gone, not mixed in
    assert not (out / LOCK).exists()  # released on failure


def test_out_is_checked_before_the_model_is_built(tmp_path, monkeypatch):
    def no_build(*args, **kwargs):
        raise AssertionError("the model was built before --out was checked")

    monkeypatch.setattr(runner, "Simulation", no_build)
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(InputError, match="not a folder") as caught:
        run(small(), tmp_path / "a_file")
    assert caught.value.key == "--out"
    with pytest.raises(InputError, match="not a folder"):
        run(small(), tmp_path / "a_file" / "below")
    with pytest.raises(InputError, match="too long"):
        run(small(), tmp_path / ("x" * 300))
    put(tmp_path / "full", {"data.csv": "1,2"})
    with pytest.raises(InputError, match="not a fenics-adaptive run folder"):
        run(small(), tmp_path / "full")


@pytest.mark.slow
def test_cli_refuses_cwd_home_and_the_config_folder_with_one_line(tmp_path):
    """`--out .`, `--out ~` (as the shell expands it) and the config's own folder hold other
    files: refused with exit status 2, one line, nothing touched."""
    home = tmp_path / "home"
    put(home, {".bashrc": "alias x=y", "thesis/chapter1.tex": "text"})
    work = tmp_path / "work"
    put(work, {"case.toml": SMALL.read_text(), "history.csv": "mine"})
    before = snapshot(tmp_path)
    for out in (".", str(home), str(work)):
        result = subprocess.run(
            [*CLI, "run", "case.toml", "--out", out, "--quiet"],
            cwd=work,
            env=dict(ENV, HOME=str(home)),
            capture_output=True,
            text=True,
        )
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "--out" in lines[0] and "--overwrite" in lines[0], lines
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------ the lock
def lock_of(pid: int, start: str | None, host: str | None = None) -> str:
    return json.dumps(
        {
            "program": "fenics-adaptive",
            "pid": pid,
            "host": host or socket.gethostname(),
            "started": "2026-01-02 03:04:05 +0000",
            "process_start": start,
            "token": "0123456789abcdef",
        }
    )


def process_start(pid: int) -> str:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]


@pytest.mark.slow
def test_a_live_lock_refuses_the_run_with_its_pid_host_and_start(tmp_path):
    out = tmp_path / "out"
    run(small(), out)
    before = snapshot(out)
    other = subprocess.Popen(["sleep", "60"])
    try:
        (out / LOCK).write_text(lock_of(other.pid, process_start(other.pid)))
        with pytest.raises(InputError) as caught:
            run(small(), out)
        message = str(caught.value)
        assert caught.value.key == "--out"
        assert f"PID {other.pid}" in message and socket.gethostname() in message
        assert "2026-01-02 03:04:05" in message
        assert snapshot(out) == {**before, LOCK: (out / LOCK).read_bytes()}
        # a lock from another host is never taken over
        (out / LOCK).write_text(lock_of(1, None, host="elsewhere.example"))
        with pytest.raises(InputError, match=r"elsewhere\.example"):
            run(small(), out)
    finally:
        other.kill()
        other.wait()


@pytest.mark.slow
@pytest.mark.parametrize("case", ["dead pid", "reused pid", "this process, inactive"])
def test_a_stale_lock_is_taken_over_with_a_notice(tmp_path, capsys, case):
    out = tmp_path / "out"
    run(small(), out)
    if case == "dead pid":
        gone = subprocess.Popen(["true"])
        gone.wait()
        text = lock_of(gone.pid, None)
    elif case == "reused pid":  # alive, but not the process that took the lock
        text = lock_of(os.getppid(), "1")
    else:  # left by an earlier, failed run in this very process
        text = lock_of(os.getpid(), process_start(os.getpid()))
    (out / LOCK).write_text(text)
    capsys.readouterr()
    assert run(small(), out)["status"] == "completed"
    assert "stale lock" in capsys.readouterr().err
    assert not (out / LOCK).exists()


@pytest.mark.slow
def test_two_runs_into_one_folder_the_second_is_refused(tmp_path):
    """A real second process: refused with the first one's PID; the first is not disturbed,
    and SIGTERM (interruption) releases its lock."""
    config = tmp_path / "long.toml"
    config.write_text(SMALL.read_text().replace("end_time = 2.0e-4", "end_time = 5.0e-2"))
    out = tmp_path / "out"
    first = subprocess.Popen(
        [*CLI, "run", str(config), "--out", str(out), "--quiet"], env=ENV, stderr=subprocess.PIPE
    )
    deadline = time.time() + 120
    while not (out / "history.partial.csv").exists():
        assert first.poll() is None and time.time() < deadline
        time.sleep(0.1)
    second = subprocess.run(
        [*CLI, "run", str(config), "--out", str(out), "--quiet"],
        env=ENV,
        capture_output=True,
        text=True,
    )
    assert first.poll() is None, "the second run disturbed the first"
    first.send_signal(signal.SIGTERM)
    _, stderr = first.communicate(timeout=120)
    assert second.returncode == 2, second.stderr
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and f"PID {first.pid}" in lines[0] and "in use" in lines[0], lines
    assert first.returncode == 130, stderr
    assert not (out / LOCK).exists()
    assert json.loads((out / "summary.json").read_text())["status"] == "interrupted"


@pytest.mark.slow
def test_the_lock_is_held_while_the_run_writes(tmp_path, monkeypatch):
    out = tmp_path / "out"
    seen = []
    original = explicit.ExplicitSolver.run

    def spy(*args, **kwargs):
        # a first run in a fresh checkout compiles its kernels with a small run of its own,
        # before the folder is opened: the run that writes is the last
        seen.append(json.loads((out / LOCK).read_text()) if (out / LOCK).exists() else None)
        return original(*args, **kwargs)

    monkeypatch.setattr(explicit.ExplicitSolver, "run", spy)
    run(small(), out)
    assert seen[-1]["pid"] == os.getpid() and seen[-1]["host"] == socket.gethostname()
    assert not (out / LOCK).exists()


def test_run_folder_refuses_a_second_holder_in_the_same_process(tmp_path):
    from mpi4py import MPI

    first = RunFolder(tmp_path / "out", MPI.COMM_WORLD)
    first.open(fresh=True)
    try:
        with pytest.raises(InputError, match=f"PID {os.getpid()}"):
            RunFolder(tmp_path / "out", MPI.COMM_WORLD).open(fresh=True)
    finally:
        first.close()
    second = RunFolder(tmp_path / "out", MPI.COMM_WORLD)
    second.open(fresh=True)
    second.close()
    assert not (tmp_path / "out" / LOCK).exists()


# ------------------------------------------------------------------ MPI
MPIEXEC = Path(sys.executable).parent / "mpiexec"


def mpi_run(*args, ranks: int = 2) -> subprocess.CompletedProcess:
    command = [str(MPIEXEC), "-n", str(ranks), *CLI, "run", *map(str, args), "--quiet"]
    return subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=300)


@pytest.mark.mpi
def test_under_mpi_the_lock_refuses_every_rank_and_a_restart_continues(tmp_path):
    """Two ranks: a held lock makes both exit with status 2 and one line; a checkpointed
    two-rank run extended with --restart gives the serial history; the manifest names every
    rank's files."""
    out = tmp_path / "out"
    config = tmp_path / "first.toml"
    text = SMALL.read_text().replace("[output]", "[output]\ncheckpoint_interval = 500")
    config.write_text(text.replace("end_time = 2.0e-4", "end_time = 1.0e-4"))
    first = mpi_run(config, "--out", out)
    assert first.returncode == 0, first.stderr
    listed = read_manifest(out)
    assert any(e.startswith("checkpoint/rank1-") for e in listed), listed
    assert "elements/elements_000001_r1.vtu" in listed
    other = subprocess.Popen(["sleep", "60"])
    try:
        (out / LOCK).write_text(lock_of(other.pid, process_start(other.pid)))
        refused = mpi_run(SMALL, "--out", out, "--restart", out)
    finally:
        other.kill()
        other.wait()
    assert refused.returncode == 2, refused.stderr
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and f"PID {other.pid}" in lines[0], lines
    (out / LOCK).unlink()
    extended = mpi_run(SMALL, "--out", out, "--restart", out)
    assert extended.returncode == 0, extended.stderr
    run(tomllib.loads(SMALL.read_text()), tmp_path / "serial")
    serial, parallel = (read_history(p / "history.csv") for p in (tmp_path / "serial", out))
    assert serial["time"] == parallel["time"]
    for column in ("reaction_force", "displacement", "internal_energy", "kinetic_energy"):
        a, b = np.array(serial[column]), np.array(parallel[column])
        assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max(), column


@pytest.mark.slow
def test_every_file_is_listed_before_it_is_written(tmp_path, monkeypatch):
    """So that a run killed at any moment leaves no file of its own that its manifest does
    not name (and that the next run would refuse or keep)."""
    from fenics_adaptive.io import checkpoint, output

    out = tmp_path / "out"
    checked = []

    def listed_first(original):
        def write(path, *args, **kwargs):
            relative = Path(path).relative_to(out).as_posix()
            assert relative in read_manifest(out), f"{relative} written before it is listed"
            checked.append(relative)
            return original(path, *args, **kwargs)

        return write

    monkeypatch.setattr(output, "write_vtu", listed_first(output.write_vtu))
    monkeypatch.setattr(checkpoint, "write_durably", listed_first(checkpoint.write_durably))
    original_run = explicit.ExplicitSolver.run

    def spy(*args, **kwargs):
        for name in ("history.partial.csv", "history.csv", "displacement.xdmf", "displacement.h5"):
            assert name in read_manifest(out), name
        return original_run(*args, **kwargs)

    monkeypatch.setattr(explicit.ExplicitSolver, "run", spy)
    run(small(output__checkpoint_interval=300), out)
    assert any(c.startswith("checkpoint/rank0-") for c in checked)
    assert any(c.startswith("plies/plies_") for c in checked)
    assert "checkpoint/checkpoint.json.partial" in checked
    files = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()} - {MANIFEST}
    assert files <= set(read_manifest(out))
