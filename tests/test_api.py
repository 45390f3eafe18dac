"""The public API: the names of ``fenics_adaptive.__all__``, imported lazily, and the example of
docs/api.md run as it stands (its own asserts check the physics: beam theory, one refinement of
the expected cells and nodes, mass and energy balance)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import fenics_adaptive

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "api.md"
PUBLIC = {
    "load_config",
    "parse_config",
    "RunConfig",
    "Simulation",
    "PythonIndicator",
    "Observer",
    "Contributor",
    "ForceKind",
    "HistoryRow",
    "RefinementEvent",
    "InterfaceState",
    "run_config",
    "InputError",
}


def code_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.M | re.S)


def test_the_public_names_are_a_small_documented_set():
    assert set(fenics_adaptive.__all__) == PUBLIC | {"__version__"}
    for name in PUBLIC:
        value = getattr(fenics_adaptive, name)
        assert value.__doc__ and len(value.__doc__.strip()) > 20, name
        assert name in dir(fenics_adaptive)
    with pytest.raises(AttributeError, match="no attribute 'structure'"):
        fenics_adaptive.structure  # noqa: B018 - internal modules are not public names


def test_importing_the_package_loads_no_runtime():
    """``import fenics_adaptive`` (and so ``fenics-adaptive --help``) stays fast: the public
    names are imported when first used; a config is read without DOLFINx and numba."""
    code = (
        "import sys, fenics_adaptive as fa\n"
        "heavy = [m for m in ('dolfinx', 'numba', 'ufl', 'petsc4py') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "config = fa.load_config('demos/esl_cantilever.toml')\n"
        "heavy = [m for m in ('dolfinx', 'numba', 'ufl', 'petsc4py') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "assert fa.Simulation.__module__ == 'fenics_adaptive.simulation'\n"
        "assert 'dolfinx' in sys.modules\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr


def test_the_page_lists_every_public_name():
    text = PAGE.read_text()
    for name in PUBLIC:
        assert f"`{name}`" in text, name


@pytest.mark.slow
def test_the_api_page_runs_and_its_checks_pass(monkeypatch, capsys):
    blocks = code_blocks(PAGE.read_text())
    assert len(blocks) >= 4
    monkeypatch.chdir(ROOT)
    namespace: dict = {"__name__": "api_page"}
    for block in blocks:
        exec(compile(block, str(PAGE), "exec"), namespace)
    assert "checks passed" in capsys.readouterr().out
    # the page's own checks ran on what it computed
    assert len(namespace["recorder"].events) == 1
    assert namespace["simulation"].t >= namespace["config"].solver.end_time * (1 - 1e-9)
