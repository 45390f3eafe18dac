"""# Triple cantilever beam: the adaptive element against the layerwise reference

The paper's first example (Figures 3-7). A 50 mm beam of eight 0-degree plies is pulled open at
one end, top arm up and bottom arm down; two delaminations (interfaces 2 and 6) run towards the
clamped end, interface 4 holding the symmetry. Five runs of the same beam:

- ``reference``: the layerwise (LW) model: one cell layer per sublaminate (plies 1-2, 3-4, 5-6,
  7-8), cohesive elements at interfaces 2 and 6;
- ``refined_from_start``: the adaptive ESL element refined everywhere at t = 0 (interfaces 2 and
  6 strong, 4 weak): the paper's "non-adaptive" run, which must match the reference exactly;
- ``adaptive``: ESL until the arm opening reaches 0.0023 mm (cohesive initiation), then refined;
- ``late``: weakly refined from the start, strongly (delaminations inserted) only at 0.005 mm,
  past the cohesive initiation: the force jump and ringing of Figure 7;
- ``late_stabilised``: the same, the strong refinement released over 0.01 ms (tie force).

Then: the propagation branch against beam-theory LEFM (P = K^1.5 / sqrt(3 E I delta),
K = sqrt(2 b E I GIc), the same for simple and root-rotation-corrected beam theory, since both
write C and G with one effective length), and the cost of a force evaluation per cell,
unrefined against refined.

    .venv/bin/python demos/tcb.py --out results/tcb          # all runs, about 4 minutes
    .venv/bin/python demos/tcb.py --out results/tcb --quick  # 20 mm beam, seconds

Writes ``results/tcb/<run>/`` (history.csv, summary.json, plots, ParaView fields: open
``elements.pvd`` to see the subelements and extra nodes), ``tcb_force_displacement.png``,
``tcb_deformed.png`` and ``summary.json`` with the comparisons. Units: N, mm, s, tonne.
"""

import json
import tomllib
from pathlib import Path
from statistics import median

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.collections import PolyCollection

from fenics_adaptive.analysis.lefm import lefm_comparison, tcb_lefm_force
from fenics_adaptive.analysis.studies import (
    TCB_LATE_OPENING,
    TCB_RUNS,
    demo_parser,
    tcb_quick,
    tcb_variant,
)
from fenics_adaptive.analysis.timing import time_call
from fenics_adaptive.errors import script_main
from fenics_adaptive.io.output import read_history
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

HERE = Path(__file__).parent
PROG = "demos/tcb.py"  # the name its messages and --help give
RUNS = TCB_RUNS


def run_all(base: dict, out: Path, names, overwrite: bool = False) -> tuple[dict, dict]:
    """Run every variant; returns (config, summary, history) and the final structures.
    ``overwrite``: as the command line's ``--overwrite`` for each run's folder."""
    results, structures = {}, {}
    for name in names:
        config = parse_config(tcb_variant(base, name), source=f"demos/tcb.toml [{name}]")
        print(f"--- {name}")
        summary, structures[name] = execute(config, out / name, overwrite=overwrite)
        results[name] = (config, summary, read_history(out / name / "history.csv"))
    return results, structures


def compare(results: dict) -> dict:
    """Each run against the reference: force after refinement, dissipation, crack length."""
    ref_config, _, ref = results["reference"]
    width = ref_config.mesh.width
    out = {}
    for name, (_, summary, h) in results.items():
        F, F_ref = np.array(h["reaction_force"]), np.array(ref["reaction_force"])
        n = min(len(F), len(F_ref))
        d = np.array(h["displacement"][:n])
        joined = d >= (0.01 if name != "reference" else 0.0)  # past any refinement
        out[name] = {
            "peak_force_N": float(np.abs(F).max()),
            "final_force_N": float(F[-1]),
            "dissipated_energy_mJ": float(h["dissipated_energy"][-1]),
            "delamination_length_per_crack_mm": float(h["delaminated_area"][-1] / (2 * width)),
            "max_force_difference_to_reference_after_0.01mm_N": float(
                np.abs(F[:n] - F_ref[:n])[joined].max()
            ),
            "steps": summary["steps"],
            "wall_time_s": summary["wall_time_s"],
            "time_per_step_s": summary["time_per_step_s"],
        }
    return out


def cost_per_cell(base: dict, repeats: int = 20) -> dict:
    """Median time of one internal-force evaluation per cell: unrefined (UFL), weakly refined
    at 2, 4, 6 and strongly refined at 2, 6 (numba subelements and cohesive elements)."""
    out = {}
    for label, initial in (("unrefined", "none"), ("weak", "weak"), ("strong", "strong")):
        data = tcb_variant(base, "refined_from_start")
        data["interfaces"]["initial"] = initial
        structure = build_structure(parse_config(data))
        rng = np.random.default_rng(0)
        structure.base.u.x.array[:] = 1e-4 * rng.standard_normal(structure.base.u.x.array.shape)
        seconds, _ = time_call(structure.internal_force, repeats, warmups=3, statistic=median)
        out[label] = seconds / structure.base.n_owned_cells
    return {
        "seconds_per_cell": out,
        "unrefined_over_strong": out["unrefined"] / out["strong"],
        "paper_unrefined_over_refined": 1.84 / 2.18,
    }


def plot(results: dict, out: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), layout="constrained")
    styles = {
        "reference": dict(color="k", lw=2.5),
        "refined_from_start": dict(color="tab:orange", lw=1.2, ls="--"),
        "adaptive": dict(color="tab:blue", lw=1.2),
        "late": dict(color="tab:red", lw=1.0),
        "late_stabilised": dict(color="tab:green", lw=1.2),
    }
    config = results["reference"][0]
    for ax, x_max in zip(axes, (None, 0.02), strict=True):
        for name, (_, _, h) in results.items():
            ax.plot(h["displacement"], h["reaction_force"], label=name, **styles[name])
        delta = np.linspace(0.02, max(results["reference"][2]["displacement"]), 200)
        ax.plot(delta, tcb_lefm_force(config, delta), ":", color="gray", label="LEFM branch")
        ax.set_xlabel("arm opening delta (mm)")
        ax.set_ylabel("reaction force on the top arm (N)")
        ax.grid(alpha=0.3)
        if x_max:
            ax.set_xlim(0, x_max)
            for value in (0.0023, TCB_LATE_OPENING):
                ax.axvline(value, color="gray", lw=0.8)
            ax.set_title("zoom: refinement at 0.0023 and 0.005 mm")
        else:
            ax.set_ylim(0, None)
            ax.set_title("triple cantilever beam")
    axes[0].legend()
    fig.savefig(out / "tcb_force_displacement.png", dpi=150)
    plt.close(fig)


def side_view(ax, structure, title: str) -> None:
    """Elements in the x-z plane (the y = 0 faces), deformed, extra nodes as dots."""
    nodes, _, _ = structure.elements()
    X = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
    u = np.vstack(
        [
            structure.base.u.x.array.reshape(-1, 3),
            structure.extra.vectors["u"].array.reshape(-1, 3),
        ]
    )
    x = X + u
    face = nodes[:, [0, 1, 5, 4]]  # y = 0 face, cyclic
    front = np.all(np.abs(X[face][:, :, 1]) < 1e-9, axis=1)
    polygons = x[face[front]][:, :, [0, 2]]
    ax.add_collection(PolyCollection(polygons, facecolor="#d8e4f0", edgecolor="k", lw=0.3))
    extra = structure.n_base + np.arange(structure.extra.n_local)
    on_front = np.abs(X[extra, 1]) < 1e-9
    ax.plot(x[extra[on_front], 0], x[extra[on_front], 2], "k.", ms=1.5)
    ax.set_title(title)
    ax.set_aspect("equal")
    ax.autoscale()
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")


def deformed(structures: dict, out: Path, length: float) -> None:
    """Paper Figure 4: the deformed reference and adaptive beams near the loaded end."""
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), layout="constrained")
    for ax, name in zip(axes, ("reference", "adaptive"), strict=True):
        side_view(ax, structures[name], f"{name} at the end of the run (extra nodes as dots)")
        ax.set_xlim(length - 15.0, length + 0.5)
    fig.savefig(out / "tcb_deformed.png", dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(prog, __doc__, HERE / "tcb.toml", "results/tcb")
    parser.add_argument("--quick", action="store_true", help="20 mm beam, for a fast look")
    args = parser.parse_args(argv)
    base = tomllib.loads(Path(args.config).read_text())
    if args.quick:
        base = tcb_quick(base)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    results, structures = run_all(base, out, RUNS, args.overwrite)
    comparison = compare(results)
    lefm = lefm_comparison(results["reference"][0], results["reference"][2])
    lefm_adaptive = lefm_comparison(results["adaptive"][0], results["adaptive"][2])
    cost = cost_per_cell(base)
    plot(results, out)
    deformed(structures, out, base["mesh"]["length"])
    summary = {
        "units": "N, mm, s, tonne (mJ)",
        "runs": comparison,
        "lefm_reference": lefm,
        "lefm_adaptive": lefm_adaptive,
        "force_evaluation_cost": cost,
        "refinement_states": {
            "none": InterfaceState.NONE,
            "weak": InterfaceState.WEAK,
            "strong": InterfaceState.STRONG,
        },
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    script_main(main, PROG)
