"""The AFEM teaching material in docs/afem cannot rot: every script runs in a fresh interpreter
and passes its own checks (the physics it demonstrates is asserted inside the script), draws its
figures without a display (saved into a temporary folder through AFEM_FIGURES), and the tutorial
index links every script and nothing that does not exist. (tests/test_docs_site.py builds the
same scripts into the documentation site.)

The scripts run two at a time (the machines have 2 cores); each one takes a few seconds.
"""

import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from helpers import FIGURES

# The scripts run once for the module (a fixture), together about a minute and a half.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).parents[1]
TUTORIAL = ROOT / "docs" / "afem"
INDEX = TUTORIAL / "README.md"
SCRIPTS = sorted(TUTORIAL.glob("[0-9][0-9]_*.py"))  # afem_figures.py is their drawing helper
TIMEOUT = 120  # s per script; they need a few seconds with warm compiler caches
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run_script(script: Path, figures: Path) -> subprocess.CompletedProcess:
    # cwd is the repository root: the scripts say to run them from there. No display: the
    # scripts must draw with the Agg backend.
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MPLBACKEND")}
    env["AFEM_FIGURES"] = str(figures / script.stem)
    return subprocess.run(
        [sys.executable, str(script)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        env=env,
    )


@pytest.fixture(scope="module")
def figure_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("afem_figures")


@pytest.fixture(scope="module")
def results(figure_dir) -> dict[str, subprocess.CompletedProcess]:
    """Every script's run, started two at a time so the whole module stays short."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = pool.map(lambda s: run_script(s, figure_dir), SCRIPTS)
        return dict(zip((s.name for s in SCRIPTS), runs, strict=True))


def test_the_tutorial_has_its_six_scripts():
    assert [s.name[:3] for s in SCRIPTS] == ["01_", "02_", "03_", "04_", "05_", "06_"]
    assert sorted(FIGURES) == [s.stem for s in SCRIPTS]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda s: s.name)
def test_script_runs_and_its_checks_pass(script, results):
    result = results[script.name]
    assert result.returncode == 0, (
        f"{script.name} exited with {result.returncode}\n"
        f"--- stdout (end)\n{result.stdout[-3000:]}\n--- stderr (end)\n{result.stderr[-3000:]}"
    )
    assert result.stdout.rstrip().endswith(f"{script.stem}: all checks passed")


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda s: s.name)
def test_script_draws_its_figures(script, results, figure_dir):
    assert results[script.name].returncode == 0, f"{script.name} failed (see the test above)"
    written = sorted(p.stem for p in (figure_dir / script.stem).glob("*.png"))
    assert written == sorted(FIGURES[script.stem]), f"{script.name} drew {written}"
    for name in written:
        data = (figure_dir / script.stem / f"{name}.png").read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 10_000, f"{name}.png is empty"


def test_every_script_is_linked_from_the_index():
    index = INDEX.read_text()
    missing = [s.name for s in SCRIPTS if f"]({s.name})" not in index]
    assert not missing, f"docs/afem/README.md does not link {missing}"


def test_every_relative_link_of_the_index_exists():
    targets = re.findall(r"\]\(([^)#\s]+)\)", INDEX.read_text())
    relative = [t for t in targets if "://" not in t]
    assert relative
    dead = [t for t in relative if not (TUTORIAL / t).exists()]
    assert not dead, f"docs/afem/README.md links missing files {dead}"
