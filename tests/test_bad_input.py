"""Bad input through the command line: exit status 2, one line on stderr that names the config
file once and the key, no Python traceback; `check` reports the size and cost of a run and
refuses one of too many steps; Ctrl-C during start-up is one line, exit status 130."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
SMALL = DATA / "small_beam.toml"
TCB = DATA / "tcb_adaptive.toml"
CLI = [sys.executable, "-m", "fenics_adaptive"]


def run_cli(*args, timeout=600):
    return subprocess.run(
        [*CLI, *map(str, args)],
        capture_output=True,
        text=True,
        env={**os.environ, "FENICS_ADAPTIVE_TRACEBACK": ""},
        timeout=timeout,
    )


def edited(tmp_path, source: Path, old: bytes | str, new: bytes | str, name="case.toml") -> Path:
    text = source.read_bytes()
    old, new = (s.encode() if isinstance(s, str) else s for s in (old, new))
    assert old in text
    path = tmp_path / name
    path.write_bytes(text.replace(old, new, 1))
    return path


BAD = [
    # (source, replace this, with this, the key (or text) the one line must name)
    (SMALL, "prototype", b"prot\xf6type", "not UTF-8"),
    (SMALL, "[mesh]", "[mesh", "not valid TOML"),
    (TCB, 'law = "bk"', 'law = ["bk"]', "cohesive.law"),
    (
        SMALL,
        "[solver]",
        '[[load]]\nface = "top"\nforce = [0, 0, nan]\nrise_time = 1e-4\n\n[solver]',
        "load[0].force[2]",
    ),
    (SMALL, "nx = 8", "nx = 1e9", "mesh.nx"),
    (SMALL, "nx = 8\nny = 2", "nx = 100000\nny = 100000", "mesh.nx"),
    (SMALL, "ply_thickness = 0.25", "ply_thickness = 1e-300", "laminate.ply_thickness"),
    (SMALL, 'face = "x0"', 'face = "x0&x1"', "clamp[0].face"),
    (SMALL, 'displacement_face = "x1"', 'displacement_face = "x0&x1"', "output.displacement_face"),
    (SMALL, "[[prescribed]]", '[[clamp]]\nface = "x1"\n\n[[prescribed]]', "prescribed[0].face"),
    (
        SMALL,
        "[solver]",
        '[impactor]\nshape = "sphere"\nradius = 5.0\nmass = 1e-5\n'
        "position = [10.0, 1.0, 8.0]\nvelocity = [0.0, 0.0, -inf]\n\n[solver]",
        "impactor.velocity[2]",
    ),
    (SMALL, "rho = 1.6e-9", "rho = 1600", "did you mean 1.6e-09 (kg/m^3 -> tonne/mm^3)"),
    (SMALL, "E1 = 100000.0", "E1 = 100e9", "materials.prototype.E1"),
    (SMALL, "end_time = 2.0e-4", "end_time = 1e300", "solver.max_steps"),
    (SMALL, "[output]", "[output]\nfields_plies = [1, 9]", "output.fields_plies[1]"),
    (
        SMALL,
        "[output]",
        "[output]\nfields_box = [0, 10, 1, 0, 0, 5]",
        "output.fields_box: y_min 1 mm is above y_max 0 mm",
    ),
    (SMALL, "[output]", "[output]\nfields_box = [0, 10]", "output.fields_box"),
    (SMALL, "fields_interval = 1.0e-4", "ply_fields_every = 2", "set fields_interval too"),
    (SMALL, "[solver]", "[solver]\nmass_scaling_step = 1e-7", "solver.mass_scaling_step"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("source", "old", "new", "named"), BAD, ids=[b[3] for b in BAD])
def test_bad_config_is_one_line_exit_2(tmp_path, source, old, new, named):
    config = edited(tmp_path, source, old, new)
    out = tmp_path / "out"
    result = run_cli("run", config, "--out", out)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr and named in lines[0], lines[0]
    assert lines[0].startswith("fenics-adaptive: ") and lines[0].count(str(config)) == 1
    assert not out.exists()  # nothing was written


@pytest.mark.slow
def test_check_reports_size_steps_and_estimates(tmp_path):
    """`check` reports the model the run builds and the steps and rows the run takes."""
    result = run_cli("check", SMALL)
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert "16 cells, 54 nodes (162 DOFs), 8 plies, 1 cell layer(s)" in text
    steps = int(re.search(r"limited by [^)]*\), (\d+) steps", text).group(1))
    rows, frames = map(int, re.search(r"(\d+) history rows, (\d+) field frames", text).groups())
    memory = float(re.search(r"peak memory ([0-9.e+-]+) GB", text).group(1))
    assert 0.2 < memory < 1.0 and "wall time" in text
    out = tmp_path / "out"
    assert run_cli("run", SMALL, "--out", out, "--quiet").returncode == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == steps
    assert summary["model"]["cells"] == 16 and summary["model"]["dofs"] == 162
    history = (out / "history.csv").read_text().strip().splitlines()
    assert len(history) - 1 == rows == 21  # a header, then one row every 1e-5 s from t = 0
    assert frames == 3  # fields every 1e-4 s: t = 0, 1e-4, 2e-4


@pytest.mark.slow
def test_check_refuses_too_many_steps_with_the_count(tmp_path):
    config = edited(tmp_path, SMALL, "mass_damping = 0.0", "mass_damping = 0.0\nmax_steps = 1000")
    result = run_cli("check", config)
    assert result.returncode == 2
    line = result.stderr.strip()
    assert "solver.max_steps" in line and "1772 steps of 1.129e-07 s" in line, line
    config = edited(tmp_path, SMALL, "mass_damping = 0.0", "time_step = 1e-307", "tiny.toml")
    result = run_cli("check", config)
    assert result.returncode == 2 and "solver.max_steps" in result.stderr


@pytest.mark.slow
@pytest.mark.parametrize(
    ("delay", "number"),
    [(1.0, signal.SIGINT), (3.0, signal.SIGINT), (3.0, signal.SIGTERM)],
)
def test_ctrl_c_during_start_up_is_one_line(tmp_path, delay, number):
    """SIGINT while importing DOLFINx (1 s) and while meshing / compiling / building (3 s): a
    500 x 500-cell plate takes 7.8 s to reach its time loop on a quiet 2-vCPU machine with
    warm caches (a 300 x 300 one took 3.4 s: at 3 s it was sometimes already stepping).
    SIGTERM likewise (PETSc's own handler, which aborted the job, is not installed)."""
    config = edited(
        tmp_path,
        SMALL,
        "length = 20.0\nwidth = 2.0\nnx = 8\nny = 2",
        "length = 500.0\nwidth = 500.0\nnx = 500\nny = 500",
    )
    out = tmp_path / "out"
    process = subprocess.Popen(
        [*CLI, "run", str(config), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(delay)
    process.send_signal(number)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert stderr.strip() == "fenics-adaptive: interrupted during start-up; nothing was run"
    assert not out.exists()
