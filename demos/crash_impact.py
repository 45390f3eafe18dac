"""# An impact that breaks the plate: ESL, adaptive and layerwise

The crash case of the method. A rigid 10 mm sphere (5 g at 50 m/s: 6.25 J) strikes the centre
of a clamped 24 x 24 mm plate of 8 IM7/8552 plies [0/45/90/-45]s, 2 mm thick, and nearly
goes through it (2.3 mm deep in the layerwise run before it turns back). Everything that
breaks a laminate acts: finite kinematics (the damaged cells co-rotate), matrix cracking and
broken fibres in every ply (crack band, tension and kink-band compression), erosion of the
cells whose fibres have all broken or that are crushed, Coulomb friction between sphere and
plate, delamination at interfaces 2, 4 and 6. Three runs of the
same plate (``crash_impact.toml``):

- ``esl``: one solid-shell cell through the 8 plies everywhere, no refinement: blind to
  delamination;
- ``adaptive``: the same mesh, refined strongly at interfaces 2, 4 and 6 where the indicators
  at their defaults ask for it;
- ``layerwise``: the reference: four cell layers (one per 2-ply sublaminate) with cohesive
  elements in the three interfaces everywhere.

    .venv/bin/python demos/crash_impact.py --out results/crash_impact

Writes ``results/crash_impact/<run>/`` (history, summary), ``crash_impact.png`` (contact force
against the sphere's travel, the energy the plate took by mechanism, the cost), ``cscan.png``
(damage of each interface seen from above) and ``summary.json``: each run's peak force, the
energy the sphere lost and where it went (fibres, matrix, delamination, friction, eroded
cells, what the plate still holds), the sphere's exit velocity, the delaminated area per
interface and the wall time. About 4 minutes on 2 cores. Units: N, mm, s, tonne (energies
mJ, velocities mm/s).

What the energies are: the sphere's loss is the work of the contact on the plate plus what
friction dissipated; the mechanisms are summed from the damage laws' own increments, the
plate's part is its kinetic plus strain energy now. Their sum departs from the sphere's loss
by the balance built from the states (``state_energy_balance``, which checks the materials'
bookkeeping): 0.07 % of the impact energy for ESL, 1.1 and 1.6 % for the adaptive and
layerwise plates as their fibres break (README); the balance from the work
(``energy_balance``), which checks the time integration, stays within 1 mJ.
"""

from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import (
    CRASH_IMPACT_RUNS,
    MODEL_STYLES,
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
from fenics_adaptive.io.cscan import delaminated_area_per_interface, interface_damage, plot_cscan
from fenics_adaptive.settings.kinds import InterfaceState

HERE = Path(__file__).parent
PROG = "demos/crash_impact.py"  # the name its messages and --help give
# where the energy the sphere lost went, in the order the bars stack
MECHANISMS = ("fibres", "matrix", "delamination", "friction", "eroded", "plate")
COLOURS = ("tab:red", "tab:orange", "tab:purple", "tab:olive", "tab:brown", "0.7")


def energy_by_mechanism(history: dict) -> dict[str, float]:
    """mJ at the end of a run: fibre and matrix damage, delamination (cohesive), friction, the
    energy eroded cells held when they went, and what the plate still holds (kinetic plus
    strain energy)."""
    last = {name: values[-1] for name, values in history.items()}
    strain = last["internal_energy"] - last["dissipated_energy"]
    return {
        "fibres": last["fibre_dissipation"],
        "matrix": last["ply_dissipation"] - last["fibre_dissipation"],
        "delamination": last["cohesive_dissipation"],
        "friction": last.get("impactor_friction_energy", 0.0),
        "eroded": last["eroded_energy"],
        "plate": last["kinetic_energy"] + strain,
    }


def facts(structure, summary: dict, history: dict, impactor: dict) -> dict:
    """A run's numbers for summary.json (``impactor``: the config's [impactor] table)."""
    refined = (structure.interface_state == InterfaceState.STRONG).any(axis=1)
    t = np.array(history["time"])
    z = np.array(history["impactor_displacement"])
    exit_velocity = float((z[-1] - z[-2]) / (t[-1] - t[-2]))  # mm/s, negative: still going down
    initial = 0.5 * impactor["mass"] * float(np.dot(impactor["velocity"], impactor["velocity"]))
    friction = history.get("impactor_friction_energy", [0.0])[-1]
    force = np.array(history["contact_force"])
    return {
        "impact_energy_mJ": initial,
        "peak_contact_force_N": float(force.max()),
        "sphere_travel_mm": float(-z.min()),
        "exit_velocity_mm_per_s": exit_velocity,
        # through: still going down with (almost) nothing left to push
        "perforated": bool(exit_velocity < 0.0 and force[-1] < 0.05 * force.max()),
        "energy_absorbed_mJ": float(history["impact_work"][-1] + friction),
        "energy_by_mechanism_mJ": energy_by_mechanism(history),
        "delaminated_area_mm2_per_interface": delaminated_area_per_interface(structure),
        "refined_cell_fraction": float(refined.mean()) if structure.interface_state.size else 0.0,
        "eroded_elements": summary["eroded_elements_at_end"],
        "max_energy_balance_error_mJ": float(np.max(np.abs(history["energy_balance"]))),
        "state_energy_balance_mJ": float(history["state_energy_balance"][-1]),
        "wall_time_s": summary["wall_time_s"],
        "steps": summary["steps"],
    }


def plot(histories: dict, results: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4), layout="constrained")
    force, energy, cost = axes
    for name, h in histories.items():
        travel = -np.array(h["impactor_displacement"])
        force.plot(travel, h["contact_force"], label=name, **MODEL_STYLES[name])
    force.set_xlabel("sphere travel (mm)")
    force.set_ylabel("contact force (N)")
    force.set_title("contact force")
    force.grid(alpha=0.3)
    force.legend(fontsize=8)
    names = [n for n in CRASH_IMPACT_RUNS if n in results]
    bottom = np.zeros(len(names))
    for mechanism, colour in zip(MECHANISMS, COLOURS, strict=True):
        values = np.array([results[n]["energy_by_mechanism_mJ"][mechanism] for n in names])
        energy.bar(names, values, bottom=bottom, color=colour, label=mechanism)
        bottom += values
    lost = [results[n]["energy_absorbed_mJ"] for n in names]
    energy.plot(names, lost, "k_", ms=30, mew=2, label="the sphere's loss")
    energy.set_ylabel("energy (mJ)")
    energy.set_title("where the sphere's energy went")
    energy.legend(fontsize=7, loc="upper left")
    plot_cost(cost, results, CRASH_IMPACT_RUNS, ".0f")
    fig.suptitle("rigid sphere through a clamped [0/45/90/-45]s IM7/8552 plate, 6.25 J")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(
        prog, __doc__, HERE / "crash_impact.toml", "results/crash_impact", CRASH_IMPACT_RUNS
    )
    args = parser.parse_args(argv)
    runs = chosen_runs(parser, args.runs, CRASH_IMPACT_RUNS)
    base, out = study_base(args)

    results, histories, maps, refined = {}, {}, {}, {}
    study = run_study(base, runs, plate_impact_variant, out, args.overwrite, "crash_impact")
    for name, summary, structure, history in study:
        histories[name] = history
        results[name] = facts(structure, summary, history, base["impactor"])
        maps[name] = interface_damage(structure)
        cells = (structure.interface_state != InterfaceState.NONE).any(axis=1)
        refined[name] = structure.X_base[structure.bottom_local[cells]].mean(axis=1)[:, :2]
    add_ratios_to_layerwise(results, ("peak_contact_force_N", "energy_absorbed_mJ", "wall_time_s"))
    plot(histories, results, out / "crash_impact.png")
    plot_cscan(maps, refined, (base["mesh"]["length"], base["mesh"]["width"]), out / "cscan.png")
    print(write_summary(out, results, "N, mm, s, tonne (mJ, mm/s)"))

    # the check: every run kept its energy balance from the work (1 % of the impact energy)
    # and from the states (2.5 %: the materials' books), fibres broke (in the full runs, in
    # every plate), and the models that can delaminate did
    for name, r in results.items():
        assert r["max_energy_balance_error_mJ"] <= 0.01 * r["impact_energy_mJ"], name
        assert abs(r["state_energy_balance_mJ"]) <= 0.025 * r["impact_energy_mJ"], name
    assert any(r["energy_by_mechanism_mJ"]["fibres"] > 0.0 for r in results.values())
    if "layerwise" in results:
        assert results["layerwise"]["energy_by_mechanism_mJ"]["delamination"] > 0.0


if __name__ == "__main__":
    script_main(main, PROG)
