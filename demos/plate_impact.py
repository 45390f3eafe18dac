"""# Low-velocity impact on a clamped laminated plate: ESL, adaptive and layerwise

The crash-type case the adaptive element is for. A rigid sphere hits the centre of a clamped
quasi-isotropic plate. The delaminations should form under the impactor only, so only a small
part of the plate needs the layerwise description. Three runs of the same plate
(``plate_impact.toml``):

- ``esl``: one solid-shell element through the 16 plies everywhere, no refinement: cheap, and
  blind to delamination;
- ``adaptive``: the same mesh. A cell refines strongly at interfaces 4, 8 and 12 once the
  interlaminar stress recovered from equilibrium reaches 90 % of the cohesive strength, with
  two rings of neighbours; the tie force of each strong refinement is released over 0.01 ms;
- ``layerwise``: the reference: four cell layers (one per 4-ply sublaminate) and cohesive
  elements in the three interfaces everywhere.

    .venv/bin/python demos/plate_impact.py --out results/plate_impact

Writes ``results/plate_impact/<run>/`` (history, summary, energies), ``plate_impact.png``
(contact force and impactor displacement against time, energy balance, cost), ``cscan.png``
(damage of each interface seen from above, like an ultrasonic C-scan, for the adaptive and
layerwise runs) and ``summary.json`` with the peak contact force, delaminated area per
interface, refined fraction and wall time of each run. About 3 min on 2 cores (most of it the
layerwise reference). Units: N, mm, s, tonne (energy mJ).
"""

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import (
    MODEL_STYLES,
    PLATE_IMPACT_RUNS,
    chosen_runs,
    demo_parser,
    plate_impact_variant,
    plot_cost,
    run_study,
    study_base,
    write_summary,
)
from fenics_adaptive.errors import script_main
from fenics_adaptive.io.cscan import delaminated_area_per_interface, interface_damage, plot_cscan
from fenics_adaptive.settings.kinds import InterfaceState

HERE = Path(__file__).parent
PROG = "demos/plate_impact.py"  # the name its messages and --help give
RUNS = PLATE_IMPACT_RUNS


def facts(structure, summary: dict, history: dict) -> dict:
    refined = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    per_interface = delaminated_area_per_interface(structure)
    return {
        "peak_contact_force_N": float(max(history["contact_force"])),
        "time_of_peak_ms": 1e3 * history["time"][int(np.argmax(history["contact_force"]))],
        "max_impactor_displacement_mm": float(-min(history["impactor_displacement"])),
        "impact_work_mJ": float(history["impact_work"][-1]),
        "dissipated_energy_mJ": float(history["dissipated_energy"][-1]),
        "delaminated_area_mm2_per_interface": per_interface,
        "refined_cell_fraction": float(refined.mean()) if structure.interface_state.size else 0.0,
        "max_energy_balance_error_mJ": float(np.max(np.abs(history["energy_balance"]))),
        "wall_time_s": summary["wall_time_s"],
        "steps": summary["steps"],
        "time_per_step_s": summary["time_per_step_s"],
    }


def plot_histories(histories: dict, results: dict, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), layout="constrained")
    force, displacement, energy, cost = axes.ravel()
    for name, h in histories.items():
        t = 1e3 * np.array(h["time"])
        force.plot(t, h["contact_force"], label=name, **MODEL_STYLES[name])
        displacement.plot(t, h["impactor_displacement"], label=name, **MODEL_STYLES[name])
        energy.plot(t, h["energy_balance"], label=f"{name}: balance", **MODEL_STYLES[name])
    force.set_xlabel("time (ms)")
    force.set_ylabel("contact force (N)")
    force.set_title("contact force")
    displacement.set_xlabel("time (ms)")
    displacement.set_ylabel("impactor displacement (mm)")
    displacement.set_title("impactor")
    energy.set_xlabel("time (ms)")
    energy.set_ylabel("energy balance error (mJ)")
    energy.set_title("kin + int + damp - ext - impact work - refinement")
    plot_cost(cost, results, RUNS, ".0f")
    for ax in (force, displacement, energy):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("rigid sphere on a clamped [0/45/90/-45]2s plate, 625 mJ")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(prog, __doc__, HERE / "plate_impact.toml", "results/plate_impact", RUNS)
    args = parser.parse_args(argv)
    runs = chosen_runs(parser, args.runs, RUNS)
    base, out = study_base(args)

    results, histories, maps, refined = {}, {}, {}, {}
    study = run_study(base, runs, plate_impact_variant, out, args.overwrite, "plate_impact.toml")
    for name, summary, structure, history in study:
        histories[name] = history
        results[name] = facts(structure, summary, history)
        maps[name] = interface_damage(structure)
        cells = (structure.interface_state != InterfaceState.NONE).any(axis=1)
        refined[name] = structure.X_base[structure.bottom_local[cells]].mean(axis=1)[:, :2]

    if "layerwise" in results:
        reference = results["layerwise"]
        for name in set(results) - {"layerwise"}:
            r = results[name]
            r["peak_contact_force_relative_to_layerwise"] = (
                r["peak_contact_force_N"] / reference["peak_contact_force_N"] - 1.0
            )
            r["wall_time_ratio_to_layerwise"] = r["wall_time_s"] / reference["wall_time_s"]

    plot_histories(histories, results, out / "plate_impact.png")
    size = (base["mesh"]["length"], base["mesh"]["width"])
    plot_cscan(maps, refined, size, out / "cscan.png")
    print(write_summary(out, results, "N, mm, s, tonne (mJ)"))


if __name__ == "__main__":
    script_main(main, PROG)
