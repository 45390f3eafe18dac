"""# A laminated tube hit on its end by a rigid plate: ESL, adaptive and layerwise

The crash load case of a tube. A [0/90]2s IM7/8552 tube (radius 10 mm, 30 mm long, 2 mm
wall), clamped at one end, is struck on the other by a rigid plate of 0.5 kg moving along the
axis at 10 m/s (25 J), its face tilted 10 degrees from square (an oblique impact: it meets the
rim on one side first and bends the wall there): a ``[[rigid]]`` plane on every node of the
tube (``face = "all"``: both faces and, in the refined and layerwise models, the plies
between). Matrix cracking and broken fibres in every ply, erosion, delamination at the 90/0
interfaces 2 and 6. Three runs of the same tube (``tube_impact.toml``):

- ``esl``: one solid-shell cell through the 8 plies everywhere, no refinement;
- ``adaptive``: the same mesh, refined strongly at interfaces 2 and 6 where the indicators at
  their defaults ask for it;
- ``layerwise``: three cell layers (plies 1-2, 3-6, 7-8) with cohesive elements in both
  interfaces everywhere: the reference.

    .venv/bin/python demos/tube_impact.py --out results/tube_impact

Writes ``results/tube_impact/<run>/`` (history, summary), ``tube_impact.png`` (the plate's
force against its travel, the energy it gave the tube and what the tube dissipated against
time, the cost) and ``summary.json``: each run's peak force, its mean force (the plate's work
over its travel), the plate's largest travel, the energy the plate lost, the energy
dissipated (ply damage and delamination), the delaminated area and the wall time. About 4 min
on 2 cores. Units: N, mm, s, tonne (mJ).

What it shows and what it does not: the rim crushes and the wall under the plate bends and
delaminates; the run stops after 0.15 ms, about 1.3 mm of travel, with the plate still
moving. There is no self-contact and no contact with eroded debris, so the folds and fronds of
a progressively crushed tube are out of scope.
"""

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import (
    MODEL_STYLES,
    TUBE_IMPACT_RUNS,
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
PROG = "demos/tube_impact.py"  # the name its messages and --help give


def facts(structure, summary: dict, history: dict) -> dict:
    """A run's numbers: the plate's force along its travel (N) and travel (mm), the energy
    it gave the tube (its kinetic energy lost, mJ), what the tube dissipated and where."""
    refined = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    travel = -np.array(history["plate_displacement"])
    given = float(history["impact_work"][-1])
    return {
        "peak_force_N": float(max(history["plate_force"])),
        # the crash engineer's measure, less sensitive than the peak of a ragged plateau
        "mean_force_N": given / float(travel[-1]) if travel[-1] > 0.0 else 0.0,
        "largest_travel_mm": float(travel.max()),
        "energy_given_mJ": given,
        "dissipated_energy_mJ": float(history["dissipated_energy"][-1]),
        "delaminated_area_mm2": float(history["delaminated_area"][-1]),
        "refined_cell_fraction": float(refined.mean()) if structure.interface_state.size else 0.0,
        "max_energy_balance_error_mJ": float(np.max(np.abs(history["energy_balance"]))),
        "wall_time_s": summary["wall_time_s"],
        "steps": summary["steps"],
    }


def plot(histories: dict, results: dict, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), layout="constrained")
    force, given, dissipated, cost = axes.ravel()
    for name, h in histories.items():
        travel = -np.array(h["plate_displacement"])
        time = 1e6 * np.array(h["time"])
        force.plot(travel, 1e-3 * np.array(h["plate_force"]), label=name, **MODEL_STYLES[name])
        given.plot(time, 1e-3 * np.array(h["impact_work"]), label=name, **MODEL_STYLES[name])
        dissipated.plot(
            time, 1e-3 * np.array(h["dissipated_energy"]), label=name, **MODEL_STYLES[name]
        )
    for ax, xlabel, ylabel, title in (
        (force, "plate travel (mm)", "plate force (kN)", "force on the plate"),
        (given, "time (µs)", "energy (J)", "energy the plate gave the tube"),
        (dissipated, "time (µs)", "energy (J)", "dissipated: ply damage and delamination"),
    ):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    plot_cost(cost, results, TUBE_IMPACT_RUNS, ".1f")
    fig.suptitle("[0/90]2s tube, R 10 mm, hit on its end by a 0.5 kg plate at 10 m/s, 10° tilted")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(
        prog, __doc__, HERE / "tube_impact.toml", "results/tube_impact", TUBE_IMPACT_RUNS
    )
    args = parser.parse_args(argv)
    runs = chosen_runs(parser, args.runs, TUBE_IMPACT_RUNS)
    base, out = study_base(args)

    results, histories = {}, {}
    study = run_study(base, runs, plate_impact_variant, out, args.overwrite, "tube_impact.toml")
    for name, summary, structure, history in study:
        histories[name] = history
        results[name] = facts(structure, summary, history)
    add_ratios_to_layerwise(
        results,
        ("peak_force_N", "mean_force_N", "energy_given_mJ", "dissipated_energy_mJ", "wall_time_s"),
    )
    plot(histories, results, out / "tube_impact.png")
    print(write_summary(out, results, "N, mm, s, tonne (mJ)"))

    # the check: every run kept its energy balance (1 % of what the plate gave), and what the
    # tube dissipated is no more than the plate gave it
    for name, r in results.items():
        given = max(r["energy_given_mJ"], 1.0)
        assert r["max_energy_balance_error_mJ"] <= 0.01 * given, name
        assert r["dissipated_energy_mJ"] <= given * (1.0 + 1e-6), name


if __name__ == "__main__":
    script_main(main, PROG)
