"""docs/outputs.md documents every history column, every summary.json key and every file a run
writes, so that the documentation cannot fall behind the code: a new column, key or file without
its line in the doc fails here.

The summary keys come from two places: a static reading of ``runner.execute`` (which also sees
the keys of a failed or interrupted run) and a tiny real run (which sees keys the static reading
might miss)."""

from __future__ import annotations

import ast
import json
import re
import tomllib
from pathlib import Path

import pytest
from mpi4py import MPI  # noqa: F401  (before DOLFINx)

from fenics_adaptive.io.output import COLUMN_UNITS
from fenics_adaptive.solver.explicit import COLUMNS

ROOT = Path(__file__).parents[1]
DOC = ROOT / "docs" / "outputs.md"
RUNNER = ROOT / "fenics_adaptive" / "runner.py"
SMALL = Path(__file__).parent / "data" / "small_beam.toml"


def doc_text() -> str:
    return DOC.read_text()


def section(title: str) -> str:
    """The doc's text under the heading ``## title``, up to the next ``## `` heading."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", doc_text(), re.M | re.S)
    assert match, f"docs/outputs.md has no section '## {title}'"
    return match.group(1)


def documented(name: str, text: str | None = None) -> bool:
    """The name appears in the text (default: the whole doc) as inline code: `name` (a folder
    also as `name/`)."""
    text = doc_text() if text is None else text
    return f"`{name}`" in text or f"`{name}/`" in text


# ------------------------------------------------------------------ history.csv
def history_table() -> dict[str, list[str]]:
    """Rows ``| `column` | unit | meaning |`` of the doc's history.csv section, by column."""
    rows = {}
    for line in section("history.csv").splitlines():
        match = re.match(r"\|\s*`(\w+)`\s*\|(.*)\|\s*$", line)
        if match:
            rows.setdefault(match.group(1), [c.strip() for c in match.group(2).split("|")])
    return rows


@pytest.mark.parametrize("column", COLUMNS)
def test_every_history_column_is_documented_with_its_unit(column):
    rows = history_table()
    assert column in rows, f"history column {column!r} has no table row in docs/outputs.md"
    unit = rows[column][0].replace("²", "^2")
    assert unit == COLUMN_UNITS[column], (
        f"docs/outputs.md gives {column!r} the unit {unit!r}, output.py {COLUMN_UNITS[column]!r}"
    )


def test_every_column_has_a_unit_in_the_code():
    assert set(COLUMN_UNITS) == set(COLUMNS)


# ------------------------------------------------------------------ summary.json, statically
def _string(node: ast.AST) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _is_summary(node: ast.AST) -> bool:
    return isinstance(node, ast.Name) and node.id == "summary"


def runner_summary_keys() -> set[str]:
    """Keys ``runner.execute`` (its ``_segment`` and ``_finish``) puts into ``summary``: top
    level as ``key``, nested dict literals
    as ``parent.key``. Any change to ``summary`` that cannot be read statically fails, so that
    the test is extended rather than silently blind."""
    tree = ast.parse(RUNNER.read_text())
    functions = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
    # execute runs its segments (between re-balances) in _segment, and ends in _finish
    execute = next((f for f in functions if f.name == "_segment"), None)
    assert execute is not None, "runner.py has no _segment(): update this test"
    finish = next((f for f in functions if f.name == "_finish"), None)  # execute's last part
    keys: set[str] = set()

    def add(literal: ast.AST, prefix: str = "") -> None:
        assert isinstance(literal, ast.Dict), (
            f"line {literal.lineno}: summary gets a value this test cannot read statically"
        )
        for key, value in zip(literal.keys, literal.values, strict=True):
            name = _string(key) if key is not None else None
            assert name is not None, f"line {literal.lineno}: a summary key is not a string literal"
            keys.add(prefix + name)
            if isinstance(value, ast.Dict):
                add(value, prefix + name + ".")
            elif (
                isinstance(value, ast.Call)
                and isinstance(value.func, ast.Name)
                and any(f.name == value.func.id for f in functions)
            ):
                # "model": model_summary(...): the dict literal that helper returns
                add(returned(value.func.id), prefix + name + ".")

    def returned(helper_name: str) -> ast.AST:
        helper = next(f for f in functions if f.name == helper_name)
        return next(r.value for r in ast.walk(helper) if isinstance(r, ast.Return))

    nodes = [*ast.walk(execute), *(ast.walk(finish) if finish is not None else ())]
    for node in nodes:
        if isinstance(node, ast.Assign):
            for target in node.targets:
                if _is_summary(target):
                    value = node.value
                    if isinstance(value, ast.Call) and isinstance(value.func, ast.Name):
                        # summary = _helper(...): the dict literal that helper returns
                        value = returned(value.func.id)
                    add(value)
                elif isinstance(target, ast.Subscript) and _is_summary(target.value):
                    name = _string(target.slice)
                    assert name is not None, f"line {node.lineno}: summary[<not a literal>]"
                    keys.add(name)
                    value = node.value
                    if (
                        isinstance(value, ast.Call)
                        and isinstance(value.func, ast.Name)
                        and any(f.name == value.func.id for f in functions)
                    ):
                        # summary["x"] = _helper(...): the dict literal that helper returns
                        value = returned(value.func.id)
                    if isinstance(value, ast.Dict):
                        add(value, name + ".")
        elif isinstance(node, ast.AugAssign) and _is_summary(node.target):
            add(node.value)
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and _is_summary(node.func.value)
            and node.func.attr not in ("get", "copy", "items", "keys", "values")
        ):
            assert node.func.attr == "update", f"line {node.lineno}: summary.{node.func.attr}()"
            assert not node.keywords, f"line {node.lineno}: summary.update(key=...)"
            for argument in node.args:
                add(argument)
    return keys


def test_static_reading_finds_the_summary():
    keys = runner_summary_keys()
    assert {"status", "units", "model", "model.kind", "final.time_s", "error"} <= keys


def test_every_summary_key_of_the_runner_is_documented():
    text = section("summary.json")
    missing = sorted(key for key in runner_summary_keys() if not documented(key, text))
    assert not missing, f"summary.json keys not documented in docs/outputs.md: {missing}"


# ------------------------------------------------------------------ a tiny real run
@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The small test beam for two output intervals, with field output."""
    from fenics_adaptive.runner import run_config
    from fenics_adaptive.settings.config import parse_config

    data = tomllib.loads(SMALL.read_text())
    data["solver"]["end_time"] = 2.0e-5
    data["output"]["interval"] = 1.0e-5
    data["output"]["fields_interval"] = 1.0e-5
    out = tmp_path_factory.mktemp("tiny") / "results"
    run_config(parse_config(data, source=str(SMALL)), out, show_progress=False, log=None)
    return out


@pytest.mark.slow
def test_every_summary_key_of_a_real_run_is_documented(tiny_run):
    summary = json.loads((tiny_run / "summary.json").read_text())
    keys = set()
    for key, value in summary.items():
        keys.add(key)
        if isinstance(value, dict):
            keys.update(f"{key}.{inner}" for inner in value)
    text = section("summary.json")
    missing = sorted(key for key in keys if not documented(key, text))
    assert not missing, f"summary.json keys not documented in docs/outputs.md: {missing}"
    assert keys <= runner_summary_keys(), (
        "the run wrote keys the static reading of runner.execute did not find: "
        f"{sorted(keys - runner_summary_keys())}"
    )


@pytest.mark.slow
def test_every_file_of_a_real_run_is_documented(tiny_run):
    names = sorted(path.name for path in tiny_run.iterdir())
    assert "history.csv" in names and "elements.pvd" in names
    missing = [name for name in names if not documented(name)]
    assert not missing, f"files a run writes that docs/outputs.md does not name: {missing}"


@pytest.mark.slow
def test_history_header_is_the_documented_columns(tiny_run):
    header = (tiny_run / "history.csv").read_text().splitlines()[0].split(",")
    # each documented column with its documented unit: `<column>_<unit>`
    rows = history_table()
    units = {"mm²": "mm2"}
    assert header == [f"{c}_{units.get(rows[c][0], rows[c][0])}" for c in COLUMNS]
    examples = re.findall(r"`(\w+/\w+_\d+\.vtu)`", doc_text())
    assert examples, "the doc names no example field file such as elements/elements_000000.vtu"
    for name in examples:
        assert (tiny_run / name).exists(), f"the doc names {name}, which a run does not write"
