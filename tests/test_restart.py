"""Checkpoint and restart: a resumed run repeats the uninterrupted one to round-off, with the
refinement states, ply and cohesive damage, tie forces and damping windows of the moment it
stopped; SIGTERM leaves a checkpoint, a flushed partial history and a summary that says so."""

import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenics_adaptive.config import parse_config
from fenics_adaptive.errors import InputError
from fenics_adaptive.output import read_history
from fenics_adaptive.runner import run_config

DATA = Path(__file__).parent / "data"


def late_refinement_toml(end_time: float, checkpoint_interval: int | None = None) -> str:
    """The TCB beam refined weakly at 2e-5 s and strongly at 4e-5 s over x >= 5 mm, with a
    damping window and a tie-force release that are both open at 6e-5 s."""
    text = (DATA / "tcb_adaptive.toml").read_text()
    for old, new in (
        ('initial = "strong"', 'initial = "none"'),
        ("end_time = 2.0e-4", f"end_time = {end_time!r}"),
        ("interval = 2.0e-6", "interval = 2.0e-7"),
        ("fields_interval = 5.0e-5", ""),
    ):
        assert old in text
        text = text.replace(old, new)
    if checkpoint_interval is not None:
        text = text.replace("[output]", f"[output]\ncheckpoint_interval = {checkpoint_interval}")
    return (
        text
        + """
[[refinement]]
interfaces = [2, 4, 6]
kind = "weak"
time = 2.0e-5
x_min = 5.0

[[refinement]]
interfaces = [2, 6]
kind = "strong"
time = 4.0e-5
x_min = 5.0

[stabilisation]
damping = 5.0e4
damping_window = 5.0e-5
release_window = 3.0e-5
"""
    )


def late_refinement(end_time: float, checkpoint_interval: int | None = None) -> dict:
    return tomllib.loads(late_refinement_toml(end_time, checkpoint_interval))


def run(data: dict, out: Path, restart: Path | None = None) -> dict:
    return run_config(parse_config(data), out, show_progress=False, log=None, restart=restart)


def test_resumed_history_equals_the_uninterrupted_one(tmp_path):
    run(late_refinement(1.0e-4), tmp_path / "whole")
    first = run(late_refinement(6.0e-5, checkpoint_interval=400), tmp_path / "split")
    assert (tmp_path / "split" / "checkpoint" / "checkpoint.json").exists()
    summary = run(late_refinement(1.0e-4), tmp_path / "split", restart=tmp_path / "split")
    whole = read_history(tmp_path / "whole" / "history.csv")
    split = read_history(tmp_path / "split" / "history.csv")
    assert len(split["time"]) == len(whole["time"])
    for name, values in whole.items():
        np.testing.assert_allclose(split[name], values, rtol=1e-12, atol=1e-14, err_msg=name)
    # the split really crossed open stabilisation windows and a refined, damaged structure
    assert first["refinement_events"] == 2
    assert summary["cohesive_elements_at_end"] > 0
    assert max(whole["damping_energy"]) > 0.0


def test_restart_refuses_another_model_or_rank_count(tmp_path):
    run(late_refinement(2.0e-5, checkpoint_interval=1000), tmp_path / "a")
    other = late_refinement(4.0e-5)
    other["cohesive"]["GIc"] = 0.5
    with pytest.raises(InputError, match="config differs"):
        run(other, tmp_path / "a", restart=tmp_path / "a")
    with pytest.raises(InputError, match="no complete checkpoint"):
        run(late_refinement(4.0e-5), tmp_path / "b", restart=tmp_path / "nothing")


def test_sigterm_leaves_a_checkpoint_to_continue_from(tmp_path):
    """A run killed by SIGTERM stops with exit status 130, a checkpoint, a partial history and
    an "interrupted" summary; ``--restart`` then finishes it with the uninterrupted history."""
    config = tmp_path / "run.toml"
    config.write_text(late_refinement_toml(1.2e-3))
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parent.parent))
    command = [sys.executable, "-m", "fenics_adaptive", "run", str(config), "--out", str(out)]
    process = subprocess.Popen([*command, "--quiet"], env=env, stderr=subprocess.PIPE, text=True)
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
    assert "--restart" in stderr
    assert (out / "checkpoint" / "checkpoint.json").exists()
    assert not (out / "history.csv").exists()  # never a truncated file presented as complete
    partial = read_history(out / "history.partial.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    stopped = float(json.loads((out / "checkpoint" / "checkpoint.json").read_text())["time_s"])
    assert partial["time"][-1] <= stopped
    # finish it, and the same run without interruption
    short_end = min(1.2e-3, stopped + 2.0e-5)
    config.write_text(late_refinement_toml(short_end))
    done = subprocess.run(
        [*command, "--quiet", "--restart", str(out)], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    run(late_refinement(short_end), tmp_path / "whole")
    whole = read_history(tmp_path / "whole" / "history.csv")
    resumed = read_history(out / "history.csv")
    assert len(resumed["time"]) == len(whole["time"])
    for name, values in whole.items():
        np.testing.assert_allclose(resumed[name], values, rtol=1e-12, atol=1e-14, err_msg=name)
