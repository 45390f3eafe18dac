"""Property-based fuzzing of the config: every mutation of a valid config (types, signs,
nan/inf, huge/tiny values, missing and extra keys, swapped ranges, raw bytes of the file) either
is refused with ``InputError`` (one line) or builds and runs a few time steps through the path
the command line takes (``load_config``/``parse_config``, then ``runner.run_config``). Any other
exception, or a hang, fails the test.

Deterministic (``derandomize=True``); most mutations are refused at parse time, and at most
``MAX_RUNS`` of the accepted ones are run (the rest are parsed only), so that the test stays
within about a minute here.
"""

from __future__ import annotations

import copy
import math
import signal
import tomllib
from collections import Counter
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fenics_adaptive.errors import InputError
from fenics_adaptive.settings.config import load_config, parse_config

DATA = Path(__file__).parent / "data"
FILES = {"small_beam": DATA / "small_beam.toml", "tcb_adaptive": DATA / "tcb_adaptive.toml"}
EXAMPLES = 1000
MAX_RUNS = 8
RUN_SECONDS = 240  # a model that takes longer than this to build and step has hung


def plate_impact_like() -> dict:
    """demos/plate_impact.toml shrunk to 10 x 10 mm and 5 x 5 cells (impactor above the
    centre): an adaptive model with indicators, stabilisation, cohesive law and contact."""
    path = Path(__file__).parent.parent / "demos" / "plate_impact.toml"
    data = tomllib.loads(path.read_text())
    data["mesh"].update(length=10.0, width=10.0, nx=5, ny=5)
    data["impactor"].update(radius=3.0, position=[5.0, 5.0, 5.01])
    data["solver"]["end_time"] = 1.0e-5
    return data


BASES = {name: tomllib.loads(p.read_text()) for name, p in FILES.items()}
BASES["plate_impact"] = plate_impact_like()

OTHER_TYPES = ["text", "", [1, 2], [], {"a": 1}, {}, True, False, 7, -3, 2.5, [[0.0, 1.0]]]
FACTORS = [1e300, 1e-300, 1e12, 1e-12, 1e9, 1e-9, 1e6, 1e-6, 1e3, 1e-3, 0.0, 2.0**63]
NON_FINITE = [math.nan, math.inf, -math.inf]
EXTRA_KEYS = {
    "bogus": 1.0,
    "odd\nkey \u00e9": 1,
    "x_min": 3.0,
    "x_max": 1.0,
    "face": "top",
    "nx": 4,
    "law": "bk",
}

tally: Counter = Counter()
ran: set[tuple[str, str]] = set()


def nodes(node, path=()):
    """Every (path, value) below ``node``: tables, lists and leaves."""
    yield path, node
    if isinstance(node, dict):
        for key, value in node.items():
            yield from nodes(value, (*path, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from nodes(value, (*path, i))


def at(data, path):
    for key in path:
        data = data[key]
    return data


def set_at(data, path, value) -> None:
    at(data, path[:-1])[path[-1]] = value


@st.composite
def mutated(draw):
    """(kind of mutation, base name, the mutated dict or the mutated file bytes)."""
    kind = draw(
        st.sampled_from(["type", "sign", "nonfinite", "scale", "delete", "extra", "swap", "bytes"])
    )
    if kind == "bytes":
        name = draw(st.sampled_from(sorted(FILES)))
        raw = bytearray(FILES[name].read_bytes())
        for _ in range(draw(st.integers(1, 3))):
            where = draw(st.integers(0, len(raw) - 1))
            byte = draw(st.integers(0, 255))
            how = draw(st.sampled_from(["replace", "insert", "delete"]))
            if how == "replace":
                raw[where] = byte
            elif how == "insert":
                raw.insert(where, byte)
            else:
                del raw[where]
        return kind, name, bytes(raw)
    name = draw(st.sampled_from(sorted(BASES)))
    data = copy.deepcopy(BASES[name])
    everything = [(p, v) for p, v in nodes(data) if p]
    numbers = [
        (p, v) for p, v in everything if isinstance(v, int | float) and not isinstance(v, bool)
    ]
    tables = [(p, v) for p, v in nodes(data) if isinstance(v, dict)]
    if kind == "type":
        path, _ = draw(st.sampled_from(everything))
        set_at(data, path, copy.deepcopy(draw(st.sampled_from(OTHER_TYPES))))
    elif kind == "sign":
        path, value = draw(st.sampled_from(numbers))
        set_at(data, path, -value if value else -1.0)
    elif kind == "nonfinite":
        path, _ = draw(st.sampled_from(numbers))
        set_at(data, path, draw(st.sampled_from(NON_FINITE)))
    elif kind == "scale":
        path, value = draw(st.sampled_from(numbers))
        factor = draw(st.sampled_from(FACTORS))
        scaled = value * factor if value else factor
        set_at(
            data, path, int(scaled) if isinstance(value, int) and abs(scaled) < 2**63 else scaled
        )
    elif kind == "delete":
        path, _ = draw(st.sampled_from(everything))
        del at(data, path[:-1])[path[-1]]
    elif kind == "extra":
        path, table = draw(st.sampled_from(tables))
        key = draw(st.sampled_from(sorted(EXTRA_KEYS)))
        table[key] = EXTRA_KEYS[key]
    else:  # swap: a range's ends, or the order of a list
        ranged = [(p, t) for p, t in tables if "x_min" in t or "x_max" in t]
        lists = [(p, v) for p, v in everything if isinstance(v, list) and len(v) > 1]
        if ranged and draw(st.booleans()):
            _, table = draw(st.sampled_from(ranged))
            low, high = table.get("x_min", 0.0), table.get("x_max", 1e3)
            table["x_min"], table["x_max"] = high, low
        elif lists and draw(st.booleans()):
            path, value = draw(st.sampled_from(lists))
            set_at(data, path, [*reversed(value)])
        else:
            _, table = draw(st.sampled_from(tables))
            table["x_min"], table["x_max"] = 7.0, 2.0
    return kind, name, data


class Hung(Exception):
    pass


def _alarm(number, frame):
    raise Hung(f"no answer in {RUN_SECONDS} s")


def run_a_few_steps(config, out: Path) -> dict:
    """The CLI's run path on a config cut to a tiny end time (one to a few steps)."""
    from fenics_adaptive.runner import run_config

    end = 1.0e-8  # s: one to three steps of these models
    solver = replace(
        config.solver,
        end_time=end,
        output_interval=end,
        field_interval=None,
        checkpoint_interval=None,
    )
    config = replace(config, solver=solver)
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(RUN_SECONDS)
    try:
        return run_config(config, out, show_progress=False, log=None)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(scope="module")
def report():
    yield tally
    print(f"\nconfig fuzz: {dict(tally)}")


@pytest.mark.slow
@settings(
    max_examples=EXAMPLES,
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(case=mutated())
def test_every_mutation_is_refused_in_one_line_or_runs(case, tmp_path_factory, report):
    kind, name, mutation = case
    report["tried"] += 1
    report[f"tried: {kind}"] += 1
    try:
        if kind == "bytes":
            path = tmp_path_factory.mktemp("fuzz") / "case.toml"
            path.write_bytes(mutation)
            config = load_config(path)
        else:
            config = parse_config(mutation)
    except InputError as error:
        report["refused at parse"] += 1
        assert "\n" not in str(error) and error.key is not None
        return
    report[f"accepted: {kind}"] += 1
    if report["ran"] >= MAX_RUNS or (kind, name) in ran:  # one run per (kind, base) at most
        report["accepted, not run (cap)"] += 1
        return
    ran.add((kind, name))
    report["ran"] += 1
    try:
        summary = run_a_few_steps(config, tmp_path_factory.mktemp("run"))
    except InputError as error:
        report["refused at build"] += 1
        assert "\n" not in str(error)
        return
    assert summary["status"] == "completed" and summary["steps"] >= 1


@pytest.mark.slow
def test_the_fuzz_tried_every_class(report):
    """Runs after the property (file order): the mutations covered refusals and runs."""
    assert report["tried"] >= EXAMPLES
    assert report["refused at parse"] > EXAMPLES // 2
    assert report["ran"] >= 1
