"""The AFEM teaching material in docs/afem cannot rot: every script runs in a fresh interpreter
and passes its own checks (the physics it demonstrates is asserted inside the script), and the
tutorial index links every script and nothing that does not exist.

The scripts run two at a time (the machines have 2 cores); each one takes a few seconds.
"""

import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
TUTORIAL = ROOT / "docs" / "afem"
INDEX = TUTORIAL / "README.md"
SCRIPTS = sorted(TUTORIAL.glob("*.py"))
TIMEOUT = 120  # s per script; they need a few seconds with warm compiler caches


def run_script(script: Path) -> subprocess.CompletedProcess:
    # cwd is the repository root: the scripts say to run them from there
    return subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT
    )


@pytest.fixture(scope="module")
def results() -> dict[str, subprocess.CompletedProcess]:
    """Every script's run, started two at a time so the whole module stays short."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(zip((s.name for s in SCRIPTS), pool.map(run_script, SCRIPTS), strict=True))


def test_the_tutorial_has_its_six_scripts():
    assert [s.name[:3] for s in SCRIPTS] == ["01_", "02_", "03_", "04_", "05_", "06_"]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda s: s.name)
def test_script_runs_and_its_checks_pass(script, results):
    result = results[script.name]
    assert result.returncode == 0, (
        f"{script.name} exited with {result.returncode}\n"
        f"--- stdout (end)\n{result.stdout[-3000:]}\n--- stderr (end)\n{result.stderr[-3000:]}"
    )
    assert result.stdout.rstrip().endswith(f"{script.stem}: all checks passed")


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
