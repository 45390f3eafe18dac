"""The runs of the demos' studies as configs: each variant is the demo's base config (a TOML
table, as ``tomllib`` reads it) changed into one run, so that the demos, the tests and the
benchmarks run exactly the same cases from one definition.

Units: N, mm, s, tonne (as in the configs).

Studies (``STUDIES``):

- ``tcb``: the triple cantilever beam of ``demos/tcb.toml`` (the adaptive run): the layerwise
  reference, refined from the start, adaptive, refined late, refined late and released;
- ``four_point_bending``: ``demos/four_point_bending.toml`` (the stabilised adaptive run): the
  layerwise reference, adaptive unstabilised, adaptive;
- ``plate_impact``: ``demos/plate_impact.toml`` (the adaptive run): ESL, adaptive, layerwise;
  ``tube_crush`` (``demos/tube_crush.toml``), ``tube_impact`` (``demos/tube_impact.toml``) and
  ``crash_impact`` (``demos/crash_impact.toml``) alike;
- ``fracture_tests``: the DCB of ``demos/fracture_tests.toml``, the ENF of
  ``demos/fracture_tests_enf.toml`` and the MMB of ``demos/fracture_tests_mmb.toml`` (the
  layerwise runs; ``mmb_mixity`` makes the MMB's other mixities): layerwise, adaptive (the
  indicators at their defaults), and, outside the demo, refined from the start at the
  delaminating interface.

A variant never changes its ``base``: it works on a deep copy. ``demo_parser`` and
``chosen_runs`` are the command line the demos share, ``study_base``, ``run_study`` and
``write_summary`` the rest of their mains.
"""

from __future__ import annotations

import argparse
import copy
import itertools
import json
import math
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fenics_adaptive.analysis import lefm
from fenics_adaptive.io.output import json_safe, read_history
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import parse_config

TCB_RUNS = ("reference", "refined_from_start", "adaptive", "late", "late_stabilised")
TCB_LATE_OPENING = 0.005  # mm: the paper's late refinement, past the cohesive initiation
FOUR_POINT_BENDING_RUNS = ("reference", "adaptive_unstabilised", "adaptive")
PLATE_IMPACT_RUNS = ("esl", "adaptive", "layerwise")
TUBE_CRUSH_RUNS = PLATE_IMPACT_RUNS  # derived alike: ``plate_impact_variant``
TUBE_IMPACT_RUNS = PLATE_IMPACT_RUNS  # likewise
CRASH_IMPACT_RUNS = PLATE_IMPACT_RUNS  # likewise
FRACTURE_RUNS = ("layerwise", "adaptive")


def demo_parser(
    prog: str,
    doc: str,
    config: object,
    out: str,
    runs: tuple[str, ...] | None = None,
    overwrite: bool = True,
) -> argparse.ArgumentParser:
    """The command line of a demo: ``--config`` (default ``config``, its TOML file), ``--out``
    (default ``out``, a folder), ``--overwrite`` (unless ``overwrite`` is False) and, for a
    study of ``runs``, ``--runs`` (comma separated, all by default: ``chosen_runs``) and
    ``--end-time`` (s, default the config's). ``doc``: the demo's docstring, whose first line
    (a Markdown title) describes it."""
    parser = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0].lstrip("# "))
    parser.add_argument("--config", default=config, help="the config, TOML (default: %(default)s)")
    parser.add_argument("--out", default=out, help="folder of the results (default: %(default)s)")
    if overwrite:
        parser.add_argument(
            "--overwrite",
            action="store_true",
            help="reuse run folders that hold other files (only this program's own files go)",
        )
    if runs is not None:
        parser.add_argument("--runs", default=",".join(runs), help="which runs, comma separated")
        parser.add_argument(
            "--end-time", type=float, default=None, help="s (default: the config's)"
        )
    return parser


def chosen_runs(parser: argparse.ArgumentParser, given: str, runs: tuple[str, ...]) -> list[str]:
    """The runs named in ``given`` (``--runs``, comma separated), in its order; an unknown
    name ends the program with the parser's usage error naming the runs there are."""
    chosen = given.split(",")
    unknown = sorted(set(chosen) - set(runs))
    if unknown:
        parser.error(f"--runs: unknown {', '.join(unknown)} (runs: {', '.join(runs)})")
    return chosen


def study_base(args: argparse.Namespace) -> tuple[dict, Path]:
    """A study demo's base config table (``--config``, its end time replaced by
    ``--end-time``, s, if given) and its output folder (``--out``, made if missing)."""
    base = tomllib.loads(Path(args.config).read_text())
    if args.end_time is not None:
        base["solver"]["end_time"] = args.end_time
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return base, out


def run_study(
    base: dict,
    runs: list[str],
    make_variant: Callable[[dict, str], dict],
    out: Path,
    overwrite: bool,
    label: str,
) -> Iterator[tuple[str, dict, object, dict]]:
    """Run each of ``runs`` (``make_variant(base, run)``, its messages naming it
    ``label [run]``) into ``out / run``; yields (run, its summary, its structure at the end,
    its history as ``io.output.read_history`` gives it)."""
    for name in runs:
        print(f"--- {name}")
        config = parse_config(make_variant(base, name), source=f"{label} [{name}]")
        summary, structure = execute(config, out / name, overwrite=overwrite)
        yield name, summary, structure, read_history(out / name / "history.csv")


def write_summary(out: Path, results: dict, units: str) -> str:
    """Write ``results`` (run name -> its numbers) with their ``units`` to
    ``out / summary.json`` (NaN as "nan": valid JSON); returns the text."""
    text = json.dumps(json_safe({"units": units, "runs": results}), indent=2)
    (out / "summary.json").write_text(text + "\n")
    return text


def tcb_variant(base: dict, name: str) -> dict:
    """One run of the TCB study (``TCB_RUNS``) from ``base``, the config of the adaptive run.

    Parameters:
        base: the TCB config as a TOML table (``demos/tcb.toml``).
        name: ``reference`` (layerwise, one cell layer per ply pair, cohesive at interfaces 2
            and 6, 4 the symmetry), ``refined_from_start`` (strong from t = 0), ``adaptive``
            (``base`` as it is), ``late`` (weak from the start, strong at an arm opening of
            ``TCB_LATE_OPENING`` mm) or ``late_stabilised`` (the same, the tie force released
            over 0.01 ms).

    Returns:
        A new config table.
    """
    data = copy.deepcopy(base)
    if name == "reference":
        data["model"]["kind"] = "layerwise"
        data["mesh"]["layers"] = [2, 2, 2, 2]
        data["interfaces"] = {"delaminate": [2, 6], "symmetry": [4]}
        data.pop("refinement")
    elif name == "refined_from_start":
        data["interfaces"]["initial"] = "strong"
        data.pop("refinement")
    elif name in ("late", "late_stabilised"):
        data["interfaces"]["initial"] = "weak"
        data["refinement"] = [
            {"displacement": TCB_LATE_OPENING, "interfaces": [2, 6], "kind": "strong"},
        ]
        if name == "late_stabilised":
            data["stabilisation"] = {"release_window": 1.0e-5}  # 0.01 ms, as in the paper
    return data


def tcb_quick(data: dict) -> dict:
    """The TCB study made fast: a 20 mm beam (40 cells) opened to 0.4 mm in 1 ms (arm velocity
    420 mm/s), history every 5 us, fields every 0.25 ms (five frames). The same physics in
    seconds (the tests and ``demos/tcb.py --quick`` use it).

    Parameters:
        data: a TCB config table (``demos/tcb.toml`` or one of its variants).

    Returns:
        A new config table.
    """
    data = copy.deepcopy(data)
    data["mesh"].update(length=20.0, nx=40)
    data["solver"]["end_time"] = 1.0e-3
    for entry in data["prescribed"]:
        entry["velocity"] = np.sign(entry["velocity"]) * 420.0
    data["output"]["interval"] = 5.0e-6
    data["output"]["fields_interval"] = 2.5e-4
    return data


def four_point_bending_variant(base: dict, name: str) -> dict:
    """One run of the four-point-bending study (``FOUR_POINT_BENDING_RUNS``) from ``base``, the
    config of the stabilised adaptive run.

    Parameters:
        base: the config as a TOML table (``demos/four_point_bending.toml``).
        name: ``reference`` (layerwise: a cell layer for the bottom 90-degree block and one for
            the rest, cohesive elements at interface 4 everywhere), ``adaptive_unstabilised``
            (no stabilisation) or ``adaptive`` (``base`` as it is).

    Returns:
        A new config table.
    """
    data = copy.deepcopy(base)
    if name == "reference":
        data["model"]["kind"] = "layerwise"
        data["mesh"]["layers"] = [4, 12]
        data["interfaces"] = {"delaminate": [4]}
        data.pop("indicators")
        data.pop("stabilisation")
    elif name == "adaptive_unstabilised":
        data.pop("stabilisation")
    return data


def plate_impact_variant(base: dict, name: str) -> dict:
    """One run of the plate-impact study (``PLATE_IMPACT_RUNS``) from ``base``, the config of the
    adaptive run; the tube crush and tube impact studies' alike (``TUBE_CRUSH_RUNS``,
    ``TUBE_IMPACT_RUNS``, a tube's config).

    Parameters:
        base: the config as a TOML table (``demos/plate_impact.toml``).
        name: ``esl`` (no indicators, no refinement), ``adaptive`` (``base`` as it is) or
            ``layerwise`` (one cell layer per sublaminate between the delaminating interfaces,
            cohesive elements in them everywhere).

    Returns:
        A new config table.
    """
    if name not in PLATE_IMPACT_RUNS:
        raise ValueError(f"plate_impact_variant: no run {name!r}")
    data = copy.deepcopy(base)
    if name in ("esl", "layerwise"):
        data.pop("indicators")
        data.pop("stabilisation")
    if name == "layerwise":
        data["model"]["kind"] = "layerwise"
        plies = len(data["laminate"]["angles"])
        bounds = [0, *data["interfaces"]["delaminate"], plies]
        data["mesh"]["layers"] = [b - a for a, b in itertools.pairwise(bounds)]
    return data


# the line style of each model in the ESL / adaptive / layerwise studies' figures
MODEL_STYLES = {
    "esl": dict(color="tab:gray", lw=1.2, ls="--"),
    "adaptive": dict(color="tab:blue", lw=1.5),
    "layerwise": dict(color="k", lw=2.0, alpha=0.7),
}


def plot_cost(ax, results: dict[str, dict], runs: tuple[str, ...], fmt: str = ".0f") -> None:
    """The wall time (s) of each of ``runs`` that ``results`` holds with one, as bars on the
    matplotlib axes ``ax``, labelled with ``fmt``, in the models' colours
    (``MODEL_STYLES``)."""
    names = [n for n in runs if n in results and "wall_time_s" in results[n]]
    walls = [results[n]["wall_time_s"] for n in names]
    bars = ax.bar(names, walls, color=[MODEL_STYLES[n]["color"] for n in names])
    ax.bar_label(bars, labels=[f"{w:{fmt}} s" for w in walls])
    ax.set_ylabel("wall time (s)")
    ax.set_title("cost of the run")


def add_ratios_to_layerwise(results: dict[str, dict], keys: tuple[str, ...]) -> None:
    """Give every run of a study's ``results`` (run name -> its numbers) but the layerwise one
    ``<key>_relative_to_layerwise`` for each of ``keys``: its value over the layerwise run's
    (NaN where that is 0), in place; nothing without a layerwise run."""
    reference = results.get("layerwise")
    if reference is None:
        return
    for name in set(results) - {"layerwise"}:
        for key in keys:
            ratio = results[name][key] / reference[key] if reference[key] else math.nan
            results[name][f"{key}_relative_to_layerwise"] = ratio


def fracture_variant(base: dict, name: str) -> dict:
    """One run of a fracture test (``FRACTURE_RUNS``) from ``base``, its layerwise config.

    Parameters:
        base: the specimen's config as a TOML table (``demos/fracture_tests.toml``, the DCB,
            or ``demos/fracture_tests_enf.toml``, the ENF).
        name: ``layerwise`` (``base`` as it is), ``adaptive`` (one cell through the
            thickness, refined by the indicators at their defaults: only the films' cells
            strong at the start) or ``refined_from_start`` (one cell through the thickness,
            strong from the start at the delaminating interfaces: the layerwise model's
            equal).

    Returns:
        A new config table.
    """
    if name not in (*FRACTURE_RUNS, "refined_from_start"):
        raise ValueError(f"fracture_variant: no run {name!r}")
    data = copy.deepcopy(base)
    if name != "layerwise":
        data["model"]["kind"] = "adaptive"
        del data["mesh"]["layers"]
    if name == "adaptive":
        data["indicators"] = {}
    if name == "refined_from_start":
        data["interfaces"]["initial"] = "strong"
    return data


def mmb_mixity(base: dict, mixity: float) -> dict:
    """The MMB of ``base`` (``demos/fracture_tests_mmb.toml`` or one of its variants) at another
    mode mixity G_II / G: the lever's load arm c from simple beam theory
    (``lefm.mmb_load_arm``), and the load point's speed scaled by the load point's travel to
    the end of the propagation branch (crack at the saddle less an arm thickness,
    ``lefm.mmb_force``'s theory), so that the crack runs through the specimen in the same time
    at either mixity and the run stays as quasi-static.

    Parameters:
        base: an MMB config table.
        mixity: G_II / G, in (0, 1).

    Returns:
        A new config table.
    """
    data = copy.deepcopy(base)
    beam = lefm.MMBSpecimen.of(parse_config(base))
    end = beam.half_span - beam.arm  # the branch's last crack

    def travel(load_arm: float) -> float:
        return float(beam.compliance(end, load_arm) * beam.propagation(end, load_arm))

    load_arm = lefm.mmb_load_arm(mixity, beam.half_span)
    lever = data["lever"]
    scale = travel(load_arm) / travel(beam.load_arm)
    for key in ("velocity", "displacement"):
        if key in lever:
            lever[key] *= scale
    lever["load_arm"] = round(load_arm, 3)
    return data


def dcb_quick(data: dict) -> dict:
    """The DCB made fast: a 20 mm insert film and 25 mm of bond in 1 mm cells, opened half as
    far in 0.175 of the time. The arms' bending periods scale with the crack length squared,
    so the run stays as quasi-static (kinetic energy under 3 % of the work put in), and the
    crack still grows beyond 5 arm thicknesses from the film. The same physics in tens of
    seconds (the tests and ``demos/fracture_tests.py --quick`` use it).

    Parameters:
        data: a DCB config table (``demos/fracture_tests.toml`` or one of its variants).

    Returns:
        A new config table.
    """
    data = copy.deepcopy(data)
    insert, bond = 20.0, 25.0  # mm
    time_scale, opening_scale = 0.175, 0.5
    length = insert + bond
    data["mesh"].update(length=length, nx=round(length))
    data["delamination"][0].update(x_min=bond, x_max=length)
    for entry in data["prescribed"]:
        entry["velocity"] *= opening_scale / time_scale
        entry["rise_time"] *= time_scale
    data["solver"]["end_time"] *= time_scale
    data["output"]["interval"] *= time_scale
    return data


# the quick ENF and MMB: half-span and film (mm); the load point reaches QUICK_NEAR of the
# theory's travel at initiation in QUICK_APPROACH (s, about 4.8 bending periods), then slows
# down and reaches QUICK_PAST of its travel at a crack 1 mm short of mid-span QUICK_GROWTH (s,
# about 3.7 periods) later (past: the process zone makes the beam softer than the theory's);
# QUICK_RAMP (s) to speed up and to slow down
QUICK_HALF_SPAN, QUICK_FILM = 36.0, 27.0
QUICK_NEAR, QUICK_PAST = 0.875, 1.065
QUICK_APPROACH, QUICK_GROWTH, QUICK_RAMP = 4.0e-3, 3.1e-3, 5e-4


def _half_arms(data: dict, top_body: dict) -> None:
    """Each arm of ``data``'s first insert film keeps the half of its plies next to the film,
    one cell layer per arm; ``top_body`` (a rigid body on the top face) comes down with the
    top face. The tables are changed in place."""
    laminate, film = data["laminate"], data["delamination"][0]
    angles, interface = laminate["angles"], film["interface"]
    lower, upper = angles[:interface], angles[interface:]
    lower, upper = lower[len(lower) // 2 :], upper[: len(upper) // 2]
    laminate["angles"] = lower + upper
    data["interfaces"]["delaminate"] = [len(lower)]
    data["mesh"]["layers"] = [len(lower), len(upper)]
    film["interface"] = len(lower)
    top_body["position"][2] += laminate["ply_thickness"] * len(laminate["angles"])  # the new
    top_body["position"][2] -= laminate["ply_thickness"] * len(angles)  # less the old thickness


def _quick_drive(table: dict, travel: Callable[[float], float], data: dict) -> None:
    """Drive ``table`` (a rigid body's or the lever's) by QUICK_APPROACH to QUICK_NEAR of
    ``travel(QUICK_FILM)``, then slower, to QUICK_PAST of ``travel(QUICK_HALF_SPAN - 1)``
    QUICK_GROWTH later (``travel(a)``: the load point's travel (mm) in beam theory at a crack
    a (mm) on the propagation branch); the run ends there, its rows every 1/200 of it."""
    approach = QUICK_NEAR * travel(QUICK_FILM)
    end = QUICK_PAST * travel(QUICK_HALF_SPAN - 1.0)
    ramp = QUICK_RAMP
    fast = approach / (QUICK_APPROACH - 0.5 * ramp)  # mm/s
    # the slower speed: ``end`` reached, the travel while slowing down included
    slow = (end - approach - 0.5 * ramp * fast) / (QUICK_GROWTH + 0.5 * ramp)
    if not 0.0 < slow < fast:
        raise ValueError(f"a quick run's schedule: growth speed {slow:.4g} mm/s (fast {fast:.4g})")
    end_time = QUICK_APPROACH + ramp + QUICK_GROWTH
    curve = [[0.0, 0.0], [ramp, 1.0], [QUICK_APPROACH, 1.0], [QUICK_APPROACH + ramp, slow / fast]]
    for key in ("rise_time", "profile", "displacement"):
        table.pop(key, None)
    velocity = table["velocity"]
    table["velocity"] = [0.0, 0.0, -fast] if isinstance(velocity, list) else -fast
    table["curve"] = curve
    data["solver"]["end_time"] = end_time
    data["output"]["interval"] = end_time / 200


def enf_quick(data: dict) -> dict:
    """The ENF made fast: each arm keeps the half of its plies next to the film (0.78 mm arms
    on the demo's), the half-span is 36 mm with a0 = 27 mm (a0 / L = 0.75, stable growth as the
    demo's), in 1 mm cells. Thinner arms shorten what a propagation branch needs (from five arm
    thicknesses beyond the film to one short of the nose: 30.9 - 35.2 mm here). The nose runs
    to 87.5 % of the theory's initiation travel in 4 ms (1200 mm/s on the demo's beam) and
    from there to 1.065 x the theory's travel at a crack 1 mm short of the nose in 3.6 ms (400
    mm/s): the crack grows over about four bending periods (0.84 ms), so that the branch stays
    quasi-static while the approach is quick. The same physics in under a minute (the tests
    use it).

    Parameters:
        data: an ENF config table (``demos/fracture_tests_enf.toml`` or one of its variants):
            one cell layer per arm, rollers named ``left`` and ``right``, a ``nose``.

    Returns:
        A new config table.
    """
    data = copy.deepcopy(data)
    half_span, crack = QUICK_HALF_SPAN, QUICK_FILM
    bodies = {body["name"]: body for body in data["rigid"]}
    left, right, nose = bodies["left"], bodies["right"], bodies["nose"]
    overhang = left["position"][0]
    _half_arms(data, nose)
    length = 2.0 * (half_span + overhang)
    data["mesh"].update(length=length, nx=round(length))
    data["delamination"][0].update(x_min=length - overhang - crack, x_max=length)
    for entry in data["prescribed"]:
        if "x" in entry:  # the line under the nose that stops a slide along x
            entry["x"] = 0.5 * length
    if "displacement_x" in data["output"]:
        data["output"]["displacement_x"] = 0.5 * length
    left["position"][0], right["position"][0] = overhang, length - overhang
    nose["position"][0] = 0.5 * length
    config = parse_config(data)
    width, interface = config.mesh.width, config.delaminations[0].interface
    material = lefm.arm_moduli(config.laminate, interface, width)
    arm = lefm.arm_thickness(config.laminate, interface)

    def travel(a: float) -> float:
        force = lefm.enf_propagation_force(a, material.E1, width, arm, config.cohesive.GIIc)
        return float(force * lefm.enf_compliance(a, half_span, material.E1, material.G12,
                                                 width, arm))  # fmt: skip

    _quick_drive(nose, travel, data)
    return data


def mmb_quick(data: dict) -> dict:
    """The MMB made fast as ``enf_quick`` makes the ENF: arms of half the plies, L = 36 mm,
    a0 = 27 mm, 1 mm cells, the lever's load arm scaled with L (simple beam theory's mixity
    depends on c / L only). The load point approaches initiation and grows the crack on the
    quick ENF's schedule (``QUICK_APPROACH``, ``QUICK_GROWTH``), with the lever's travels.

    Parameters:
        data: an MMB config table (``demos/fracture_tests_mmb.toml`` or one of its
            variants): the hinges at the end x = length, the far roller at x > 0.

    Returns:
        A new config table.
    """
    data = copy.deepcopy(data)
    half_span, crack = QUICK_HALF_SPAN, QUICK_FILM
    base = lefm.MMBSpecimen.of(parse_config(data))
    bodies = {body["name"]: body for body in data["rigid"]}
    lever = data["lever"]
    saddle = bodies[lever["saddle"]]
    roller = next(b for b in data["rigid"] if b is not saddle)
    overhang = roller["position"][0]
    _half_arms(data, saddle)
    length = overhang + 2.0 * half_span
    data["mesh"].update(length=length, nx=round(length))
    data["delamination"][0].update(x_min=length - crack, x_max=length)
    saddle["position"][0] = length - half_span
    lever["load_arm"] = round(base.load_arm * half_span / base.half_span, 3)
    beam = lefm.MMBSpecimen.of(parse_config(data))

    def travel(a: float) -> float:
        return float(beam.compliance(a) * beam.propagation(a))

    _quick_drive(lever, travel, data)
    return data


@dataclass(frozen=True)
class Study:
    """The runs of one demo's study and how each is derived from the demo's config."""

    runs: tuple[str, ...]
    """Names of the runs, in the order the demo runs them."""
    make_variant: Callable[[dict, str], dict]
    """``make_variant(base, run)``: the config table of one run."""


STUDIES: dict[str, Study] = {
    "tcb": Study(TCB_RUNS, tcb_variant),
    "four_point_bending": Study(FOUR_POINT_BENDING_RUNS, four_point_bending_variant),
    "plate_impact": Study(PLATE_IMPACT_RUNS, plate_impact_variant),
    "tube_crush": Study(TUBE_CRUSH_RUNS, plate_impact_variant),
    "tube_impact": Study(TUBE_IMPACT_RUNS, plate_impact_variant),
    "crash_impact": Study(CRASH_IMPACT_RUNS, plate_impact_variant),
    "fracture_tests": Study(FRACTURE_RUNS, fracture_variant),
}
"""Every study by the name of its demo (``demos/<name>.py`` and ``demos/<name>.toml``)."""


def variant(study: str, base: dict, run: str) -> dict:
    """The config table of run ``run`` of the study ``study`` (a key of ``STUDIES``).

    Parameters:
        study: the study's name, e.g. ``"tcb"``.
        base: the demo's config as a TOML table.
        run: one of the study's runs.

    Returns:
        A new config table.

    Raises:
        KeyError: an unknown study or run, naming the known ones.
    """
    if study not in STUDIES:
        raise KeyError(f"unknown study {study!r} (known: {', '.join(STUDIES)})")
    runs = STUDIES[study].runs
    if run not in runs:
        raise KeyError(f"study {study!r} has no run {run!r} (runs: {', '.join(runs)})")
    return STUDIES[study].make_variant(base, run)
