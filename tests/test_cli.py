"""The command-line program end to end: what a run writes, and how bad input is refused."""

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from fenics_adaptive.io.output import read_history

SMALL = Path(__file__).parent / "data" / "small_beam.toml"
CLI = [sys.executable, "-m", "fenics_adaptive"]
ROOT = Path(__file__).parents[1]


def run_cli(*args, cwd=None):
    return subprocess.run(
        [*CLI, *map(str, args)], capture_output=True, text=True, cwd=cwd, env=os.environ.copy()
    )


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("small") / "results"
    result = run_cli("run", SMALL, "--out", out)
    assert result.returncode == 0, result.stderr
    return out, result


@pytest.mark.slow
def test_run_writes_every_result(small_run):
    out, result = small_run
    for name in ("history.csv", "summary.json", "force_displacement.png", "energies.png"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "displacement.xdmf").is_file() and (out / "displacement.h5").is_file()
    assert (out / "cohesive.pvd").is_file() and (out / "elements.pvd").is_file()
    assert not (out / "history.partial.csv").exists()
    assert "time step" in result.stdout


@pytest.mark.slow
def test_history_and_summary_are_consistent(small_run):
    out, _ = small_run
    history = read_history(out / "history.csv")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed"
    assert summary["units"].startswith("N, mm, s, tonne")
    assert set(history) >= {
        "time",
        "displacement",
        "reaction_force",
        "kinetic_energy",
        "internal_energy",
        "external_work",
        "dissipated_energy",
        "time_step",
    }
    assert history["time"][0] == 0.0
    assert history["time"][-1] == pytest.approx(2.0e-4, rel=1e-3)
    assert history["displacement"][-1] == pytest.approx(0.05, rel=1e-12)
    assert summary["peak_reaction_force_N"] == pytest.approx(
        max(history["reaction_force"], key=abs)
    )
    # the work of the actuator is all accounted for
    # the balance of the scheme's energies closes to round-off
    assert summary["max_energy_balance_error_relative"] < 1e-12
    assert summary["model"]["total_mass_tonne"] == pytest.approx(20 * 2 * 2 * 1.6e-9, rel=1e-12)


@pytest.mark.slow
def test_check_reports_what_the_run_does(small_run):
    """``check`` gives the run's time step, step count, history rows and field frames."""
    out, _ = small_run
    result = run_cli("check", SMALL)
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    step = float(re.search(r"time step (\S+) s", result.stdout).group(1))
    assert step == pytest.approx(summary["time_step"]["used_s"], rel=1e-4)
    assert int(re.search(r"(\d+) steps to", result.stdout).group(1)) == summary["steps"]
    rows = int(re.search(r"(\d+) history rows", result.stdout).group(1))
    assert rows == len(read_history(out / "history.csv")["time"])
    frames = int(re.search(r"(\d+) field frames", result.stdout).group(1))
    assert frames == len(list((out / "elements").glob("*.vtu")))
    assert re.search(r"\d+ cells, \d+ nodes \(\d+ DOFs\), 8 plies", result.stdout)
    assert "peak memory" in result.stdout


def write_config(tmp_path, replace: tuple[str, str]) -> Path:
    text = SMALL.read_text()
    assert replace[0] in text
    path = tmp_path / "config.toml"
    path.write_text(text.replace(*replace))
    return path


@pytest.mark.slow
def test_bad_config_stops_before_the_run_with_one_line(tmp_path):
    config = write_config(tmp_path, ("nx = 8", "nx = -8"))
    out = tmp_path / "out"
    result = run_cli("run", config, "--out", out)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "mesh.nx" in lines[0]
    assert not out.exists()


@pytest.mark.slow
def test_time_step_above_the_stable_one_is_refused(tmp_path):
    config = write_config(tmp_path, ("mass_damping = 0.0", "mass_damping = 0.0\ntime_step = 1e-6"))
    result = run_cli("run", config, "--out", tmp_path / "out")
    assert result.returncode == 2
    assert "solver.time_step" in result.stderr and "stable" in result.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_forced_time_step_below_the_stable_one_is_used(tmp_path):
    config = write_config(tmp_path, ("mass_damping = 0.0", "mass_damping = 0.0\ntime_step = 5e-8"))
    out = tmp_path / "out"
    assert run_cli("run", config, "--out", out, "--quiet").returncode == 0
    assert set(read_history(out / "history.csv")["time_step"]) == {5e-8}


def test_the_restart_hint_is_shell_quoted(tmp_path, monkeypatch, capsys):
    """On SIGINT/SIGTERM the program prints the command to continue; with spaces and quotes
    in the paths it still splits back into exactly the program's arguments."""
    from fenics_adaptive import cli, runner
    from fenics_adaptive.solver.explicit import Interrupted

    config = tmp_path / "my case's dir" / "run 1.toml"
    config.parent.mkdir()
    config.write_text(SMALL.read_text())
    out = tmp_path / "results; rm -rf x" / "out dir"
    seen = {}

    def interrupted(*args, **kwargs):
        seen.update(kwargs)
        raise Interrupted(1.0e-5, 64)

    monkeypatch.setattr(runner, "run_config", interrupted)
    assert cli.main(["run", str(config), "--out", str(out), "--overwrite"]) == 130
    line = capsys.readouterr().err.strip().splitlines()[-1]
    command = shlex.split(line.split("continue with: ")[1])
    assert command == ["fenics-adaptive", "run", str(config), "--out", str(out), "--restart",
                       str(out)]  # fmt: skip
    assert seen["overwrite"] is True


@pytest.mark.slow
def test_out_that_is_a_file_is_refused_with_one_line(tmp_path):
    (tmp_path / "taken").write_text("a file")
    result = run_cli("run", SMALL, "--out", tmp_path / "taken")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--out" in lines[0] and "not a folder" in lines[0], lines
    assert (tmp_path / "taken").read_text() == "a file"


def test_help_lists_the_exit_statuses_and_where_the_docs_are(capsys):
    """``--help`` names every exit status the command returns (the module docstring's list)
    and documentation files that exist."""
    from fenics_adaptive import cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    listed = {int(m) for m in re.findall(r"^\s+(\d+)\s{2,}\S", text, flags=re.MULTILINE)}
    source = Path(cli.__file__).read_text()
    returned = {
        int(m)
        for m in re.findall(r"return (\d+)\b|fail_ranks\(\s*errors,\s*(\d+)", source)
        for m in m
        if m
    }
    assert listed == {0, 1, 2, 3, 130}
    assert returned <= listed, returned - listed
    for path in re.findall(r"docs/\w+\.md", text):
        assert (ROOT / path).is_file(), path


# ------------------------------------------------------------------ init and demo
def test_init_writes_a_starting_config_that_runs_and_never_overwrites(tmp_path):
    """The starting config parses as it is (ESL), and with its "#>" lines uncommented as the
    adaptive model it names; an existing file is refused (left as it was) unless --force."""
    from fenics_adaptive.settings.config import load_config

    case = tmp_path / "case.toml"
    result = run_cli("init", case)
    assert result.returncode == 0, result.stderr
    text = case.read_text()
    assert "Units: N, mm, s, tonne" in text
    config = load_config(case)
    assert config.kind == "esl" and config.laminate.n_plies == 8
    adaptive = tmp_path / "adaptive.toml"
    adaptive.write_text(
        re.sub(r"(?m)^#> ?", "", text).replace('kind = "esl" ', 'kind = "adaptive" ', 1)
    )
    config = load_config(adaptive)
    assert config.kind == "adaptive" and config.interfaces.delaminate == (4,)
    assert config.indicators is not None and config.cohesive.GIc == 0.4
    case.write_text("mine")
    for args in (("init", case), ("init", tmp_path)):
        result = run_cli(*args)
        assert result.returncode == 2 and len(result.stderr.splitlines()) == 1, result.stderr
    assert case.read_text() == "mine"
    assert run_cli("init", case, "--force").returncode == 0
    assert case.read_text() == text


def test_demo_lists_every_demo_and_refuses_an_unknown_one():
    from fenics_adaptive import demos

    assert sorted(demos.NAMES) == sorted(
        p.stem for p in (ROOT / "demos").glob("*.py") if p.stem != "__init__"
    )
    result = run_cli("demo")
    assert result.returncode == 0
    for name in demos.NAMES:
        assert re.search(rf"(?m)^  {name}\s+\S", result.stdout), name
    result = run_cli("demo", "nope")
    assert result.returncode == 2 and "esl_cantilever" in result.stderr
    result = run_cli("demo", "tcb", "--help")
    assert result.returncode == 0 and "usage: fenics-adaptive demo tcb" in result.stdout


@pytest.mark.slow
def test_demo_runs_from_the_package_and_checks_itself(tmp_path):
    """`fenics-adaptive demo esl_cantilever`, from a folder outside the source tree, on a
    coarser copy of its config: results in --out and a tip deflection within 3 % of beam
    theory with shear."""
    import tomllib

    from helpers import toml_text

    data = tomllib.loads((ROOT / "demos" / "esl_cantilever.toml").read_text())
    data["mesh"].update(nx=20, ny=1)
    config = tmp_path / "coarse.toml"
    config.write_text(toml_text(data))
    out = tmp_path / "results"
    result = run_cli("demo", "esl_cantilever", "--config", config, "--out", out, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["beam_theory"]["relative_difference"]) < 0.03
    assert (out / "cantilever_vs_beam_theory.png").stat().st_size > 0


# ------------------------------------------------------------------ an incomplete install
_WITHOUT = """
import sys

class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in sys.argv[1].split(","):
            raise ImportError(f"No module named {name!r}")

sys.meta_path.insert(0, Refuse())
from fenics_adaptive.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize(
    ("missing", "named"),
    [("dolfinx", "DOLFINx"), ("mpi4py,dolfinx", "mpi4py"), ("gmsh", "libglu1-mesa")],
)
def test_a_missing_dependency_is_one_line_with_how_to_install_it(missing, named):
    def cli(*args):
        return subprocess.run(
            [sys.executable, "-c", _WITHOUT, missing, *map(str, args)],
            capture_output=True,
            text=True,
        )

    result = cli("check", SMALL)
    assert result.returncode == 3, result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert named in line and "install" in line and "Traceback" not in line
    if missing != "gmsh":
        assert "fenics-adaptive[native]" in line
    # what needs no runtime still answers
    assert cli("--version").returncode == 0
    assert cli("demo").returncode == 0
