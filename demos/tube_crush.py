"""# A laminated tube crushed sideways by a rigid pole: ESL, adaptive and layerwise

A crash case on a curved part. A [0/90]2s carbon/epoxy tube (radius 15 mm, 60 mm long, 2 mm
wall), clamped at both ends, is pressed across its middle by a rigid cylinder of 5 mm radius
(a pole) driven down at 5 m/s, 3 mm deep. Its wall flattens under the pole and bends around
it; the plies slide over each other and the 90/0 interfaces a quarter of the wall in from
each face (2 and 6) delaminate. Three runs of the same tube (``tube_crush.toml``):

- ``esl``: one solid-shell cell through the 8 plies everywhere, no refinement: blind to
  delamination;
- ``adaptive``: the same mesh, refined strongly at interfaces 2 and 6 where the indicators at
  their defaults ask for it (the interface stress recovered from equilibrium, the wall's
  curvature included, at 90 % of the cohesive strength);
- ``layerwise``: three cell layers (plies 1-2, 3-6, 7-8) with cohesive elements in both
  interfaces everywhere: the reference.

    .venv/bin/python demos/tube_crush.py --out results/tube_crush

Writes ``results/tube_crush/<run>/`` (history, summary), ``tube_crush.png`` (the pole's force
and the energy it put in against its travel, the delaminated area, the cost) and
``summary.json``: each run's peak force, the energy absorbed (the pole's work, mJ), the
delaminated area and the wall time. About a minute on 2 cores. Units: N, mm, s, tonne (mJ).

What it shows and what it does not: the tube does not fold or break (no fibre failure, no
self-contact; progressive crushing is out of scope), the run stops at a set depth. A rigid
plate striking a tube's end is ``demos/tube_impact.py``.
"""

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import (
    MODEL_STYLES,
    TUBE_CRUSH_RUNS,
    add_ratios_to_layerwise,
    chosen_runs,
    demo_parser,
    plate_impact_variant,
    plot_cost,
    run_study,
    study_base,
    write_summary,
)
from fenics_adaptive.errors import script_main
from fenics_adaptive.settings.kinds import InterfaceState

HERE = Path(__file__).parent
PROG = "demos/tube_crush.py"  # the name its messages and --help give


def absorbed(history: dict) -> np.ndarray:
    """The pole's work on the tube so far (mJ): its force integrated over its travel down."""
    force = np.array(history["pole_force"])
    travel = -np.array(history["pole_displacement"])
    return np.concatenate([[0.0], np.cumsum(0.5 * (force[1:] + force[:-1]) * np.diff(travel))])


def facts(structure, summary: dict, history: dict) -> dict:
    refined = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    energy = absorbed(history)
    return {
        "peak_force_N": float(max(history["pole_force"])),
        "depth_mm": float(-history["pole_displacement"][-1]),
        "energy_absorbed_mJ": float(energy[-1]),
        "dissipated_energy_mJ": float(history["dissipated_energy"][-1]),
        "delaminated_area_mm2": float(history["delaminated_area"][-1]),
        "refined_cell_fraction": float(refined.mean()) if structure.interface_state.size else 0.0,
        "max_energy_balance_error_mJ": float(np.max(np.abs(history["energy_balance"]))),
        "wall_time_s": summary["wall_time_s"],
        "steps": summary["steps"],
    }


def plot(histories: dict, results: dict, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), layout="constrained")
    force, energy, area, cost = axes.ravel()
    for name, h in histories.items():
        depth = -np.array(h["pole_displacement"])
        force.plot(depth, h["pole_force"], label=name, **MODEL_STYLES[name])
        energy.plot(depth, absorbed(h), label=name, **MODEL_STYLES[name])
        area.plot(depth, h["delaminated_area"], label=name, **MODEL_STYLES[name])
    for ax, ylabel, title in (
        (force, "pole force (N)", "force"),
        (energy, "energy absorbed (mJ)", "the pole's work"),
        (area, "delaminated area (mm²)", "delamination, interfaces 2 and 6"),
    ):
        ax.set_xlabel("pole travel (mm)")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    plot_cost(cost, results, TUBE_CRUSH_RUNS, ".1f")
    fig.suptitle("[0/90]2s tube, R 15 mm, crushed sideways by a rigid pole at 5 m/s")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(
        prog, __doc__, HERE / "tube_crush.toml", "results/tube_crush", TUBE_CRUSH_RUNS
    )
    args = parser.parse_args(argv)
    runs = chosen_runs(parser, args.runs, TUBE_CRUSH_RUNS)
    base, out = study_base(args)

    results, histories = {}, {}
    study = run_study(base, runs, plate_impact_variant, out, args.overwrite, "tube_crush.toml")
    for name, summary, structure, history in study:
        histories[name] = history
        results[name] = facts(structure, summary, history)
    add_ratios_to_layerwise(results, ("peak_force_N", "energy_absorbed_mJ", "wall_time_s"))
    plot(histories, results, out / "tube_crush.png")
    print(write_summary(out, results, "N, mm, s, tonne (mJ)"))

    # the check: every run kept its energy balance (1 % of what the pole put in), and the
    # models that can delaminate did, and are softer for it than ESL
    for name, r in results.items():
        assert r["max_energy_balance_error_mJ"] <= 0.01 * max(r["energy_absorbed_mJ"], 1.0), name
    if {"esl", "layerwise"} <= set(results) and results["layerwise"]["delaminated_area_mm2"] > 0:
        assert results["layerwise"]["peak_force_N"] <= results["esl"]["peak_force_N"]


if __name__ == "__main__":
    script_main(main, PROG)
