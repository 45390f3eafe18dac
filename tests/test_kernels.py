"""Numba kernels compiled before the time loop (``fenics_adaptive.kernels``): every kernel
module is known, the warm-up models are valid configs, and a first run on an empty cache says
it compiles, stops at Ctrl-C during it, and keeps the compilation out of its step timings."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fenics_adaptive import kernels
from fenics_adaptive.settings.config import parse_config

ROOT = Path(__file__).parents[1]
TCB = ROOT / "tests" / "data" / "tcb_adaptive.toml"


def test_every_module_with_a_kernel_is_listed():
    defining = {
        ".".join(path.relative_to(ROOT).with_suffix("").parts)
        for path in (ROOT / "fenics_adaptive").rglob("*.py")
        if "njit" in path.read_text() and path.name != "kernels.py"
    }
    assert defining == set(kernels.KERNEL_MODULES)
    assert len(kernels.kernels()) >= 40


@pytest.mark.parametrize("variant", kernels.VARIANTS)
def test_the_warm_up_models_are_valid_configs(variant):
    config = parse_config(kernels.warm_up_config(variant))
    assert config.ply_damage == (variant == "ply_damage")
    assert kernels.variant_of(config) == variant
    assert config.impactor is not None and config.indicators is not None
    with pytest.raises(ValueError):
        kernels.warm_up_config("plastic")


def run_in_empty_cache(cache: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "fenics_adaptive", "run", TCB, "--out", out],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(cache)},
    )


@pytest.mark.slow
def test_a_first_run_compiles_before_its_time_loop_and_stops_at_ctrl_c(tmp_path):
    cache = tmp_path / "numba"
    # Ctrl-C during the compilation: start-up, so the run stops at once, nothing run
    run = run_in_empty_cache(cache, tmp_path / "stopped")
    for line in run.stdout:
        if line.startswith("compiling the numba kernels"):
            assert "first run only" in line and "Ctrl-C" in line
            break
    time.sleep(2.0)
    sent = time.perf_counter()
    run.send_signal(signal.SIGINT)
    _, stderr = run.communicate(timeout=60)
    assert run.returncode == 130, stderr
    assert time.perf_counter() - sent < 10.0
    assert "interrupted during start-up; nothing was run" in stderr
    # the whole first run: compiled before the loop, then a second run compiles nothing
    first = run_in_empty_cache(cache, tmp_path / "first")
    stdout, stderr = first.communicate(timeout=600)
    assert first.returncode == 0, stderr
    assert "compiling the numba kernels" in stdout
    second = run_in_empty_cache(cache, tmp_path / "second")
    stdout, stderr = second.communicate(timeout=600)
    assert second.returncode == 0, stderr
    assert "compiling" not in stdout
    summaries = [
        json.loads((tmp_path / n / "summary.json").read_text()) for n in ("first", "second")
    ]
    # (what the interrupted run compiled is cached already: the rest)
    assert summaries[0]["kernel_compile_time_s"] > 0.5
    assert summaries[1]["kernel_compile_time_s"] == 0.0
    # numba's own record of what it compiled inside the loops (not its disk-cache loads): nothing
    assert summaries[0]["kernels_compiled_in_loop"] == []
    assert summaries[1]["kernels_compiled_in_loop"] == []
