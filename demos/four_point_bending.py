"""# Matrix-crack-induced delamination in four-point bending

The paper's second example (Figure 8). A [90_4/0_4]s IM7/8552 beam is bent between rollers;
the bottom 90-degree block cracks between the loading points and a delamination grows from the
crack tips along the bottom 90/0 interface (interface 4). The ply damage model is the same in
all runs:

- ``reference``: the layerwise model: one cell layer for the bottom 90-degree block, one for
  the rest, cohesive elements between them everywhere;
- ``adaptive_unstabilised``: ESL cells; when the lowermost ply's failure index reaches 1 the
  cell refines weakly at interface 4 (with 3 cells on each side), strongly 0.2 ms later; no
  stabilisation;
- ``adaptive``: the same with the paper's stabilisation: damping for 0.2 ms after the weak
  refinement, the strong refinement released over 0.02 ms.

The refined region grows ring by ring as the crack spreads. Extra nodes on its border follow
the unrefined neighbours (``fenics_adaptive.model.border``), so the region does not end in a hinge.

The ESL cell's enhanced thickness strain (``fenics_adaptive.element.solid_shell``) keeps the
Poisson effect of bending out of its thickness stress: the bottom 90-degree block cracks at a
loading-roller displacement of 0.434 mm in the ESL cells against 0.439 mm in the LW reference
(with the compatible thickness strain alone, ``[model] enhanced_strain = false``: about 0.25
against 0.38 mm). The block then cracks in more columns in the adaptive runs than in LW (30-32
of 40 against 19), and the paper's rule refines around every cracked lowermost ply: most of
the cells refine.

    .venv/bin/python demos/four_point_bending.py --out results/four_point_bending

Geometry, layup and material (with its source) are documented in four_point_bending.toml.
Writes ``results/four_point_bending/<run>/`` and ``four_point_bending.png`` (force against the
loading-roller displacement, like Figure 8) and ``summary.json``. Units: N, mm, s, tonne.
"""

import json
import tomllib
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import (
    FOUR_POINT_BENDING_RUNS,
    demo_parser,
    four_point_bending_variant,
)
from fenics_adaptive.errors import script_main
from fenics_adaptive.io.output import read_history
from fenics_adaptive.materials.ply_damage import S_D
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.solver.explicit import Diverged

HERE = Path(__file__).parent
PROG = "demos/four_point_bending.py"  # the name its messages and --help give
RUNS = FOUR_POINT_BENDING_RUNS


def facts(structure, summary: dict, history: dict) -> dict:
    """Headline numbers of one run."""
    comm = structure.comm
    cracked = structure.damage_state[:, :4, S_D].max(axis=1) > 0.5  # 90-degree block, per cell
    refined = (structure.interface_state != InterfaceState.NONE).any(axis=1)
    n_cells = comm.allreduce(structure.base.n_owned_cells)
    force = np.abs(np.array(history["reaction_force"]))
    return {
        "peak_force_N": float(force.max()),
        "displacement_at_peak_mm": float(abs(history["displacement"][int(force.argmax())])),
        "dissipated_energy_mJ": float(history["dissipated_energy"][-1]),
        "delaminated_area_mm2": float(history["delaminated_area"][-1]),
        "cells_with_a_cracked_90_block": int(comm.allreduce(int(cracked.sum()))),
        "refined_cell_fraction": comm.allreduce(int(refined.sum())) / n_cells,
        "wall_time_s": summary["wall_time_s"],
        "time_per_step_s": summary["time_per_step_s"],
    }


def smooth(values: np.ndarray, width: int) -> np.ndarray:
    """Moving average over ``width`` rows (the force rings after every crack; the mean shows
    the trend)."""
    kernel = np.ones(width) / width
    return np.convolve(np.pad(values, width // 2, mode="edge"), kernel, mode="valid")[: len(values)]


def plot(histories: dict, path: Path) -> None:
    """Force against roller displacement (raw and smoothed), and the delaminated area and the
    dissipated energy, like the paper's Figure 8."""
    styles = {
        "reference": dict(color="k", lw=2.0),
        "adaptive_unstabilised": dict(color="tab:red", lw=1.2),
        "adaptive": dict(color="tab:blue", lw=1.2),
    }
    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(7, 7), layout="constrained", sharex=True, height_ratios=(3, 2)
    )
    for name, h in histories.items():
        d = np.abs(np.array(h["displacement"]))
        force = np.abs(np.array(h["reaction_force"]))
        label = name.replace("_", " ")
        top.plot(d, force, color=styles[name]["color"], lw=0.4, alpha=0.35)
        top.plot(d, smooth(force, 25), label=f"{label} (moving mean)", **styles[name])
        bottom.plot(d, h["delaminated_area"], label=f"{label}: delaminated area", **styles[name])
        bottom.plot(
            d, h["dissipated_energy"], ls="--", label=f"{label}: dissipated energy", **styles[name]
        )
    top.set_ylabel("force on the loading roller (N, half beam)")
    top.set_title("four-point bending, [90_4/0_4]s IM7/8552")
    bottom.set_xlabel("loading roller displacement (mm)")
    bottom.set_ylabel("area (mm$^2$) / energy (mJ)")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(
        prog, __doc__, HERE / "four_point_bending.toml", "results/four_point_bending"
    )
    parser.add_argument(
        "--plot-only", action="store_true", help="redraw the plot from the results in --out"
    )
    args = parser.parse_args(argv)
    base = tomllib.loads(Path(args.config).read_text())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.plot_only:
        histories = {}
        for name in RUNS:
            for file in ("history.csv", "history.partial.csv"):
                if (out / name / file).exists():
                    histories[name] = read_history(out / name / file)
                    break
        plot(histories, out / "four_point_bending.png")
        return

    results, histories = {}, {}
    for name in RUNS:
        print(f"--- {name}")
        config = parse_config(
            four_point_bending_variant(base, name), source=f"four_point_bending.toml [{name}]"
        )
        try:
            summary, structure = execute(config, out / name, overwrite=args.overwrite)
        except Diverged as error:  # the run's own summary.json says so too
            print(f"{name}: {error}")
            histories[name] = read_history(out / name / "history.partial.csv")
            results[name] = {"diverged": str(error)}
            continue
        histories[name] = read_history(out / name / "history.csv")
        results[name] = facts(structure, summary, histories[name])

    reference = results["reference"]
    for name in RUNS[1:]:
        r = results[name]
        if "diverged" in r or "diverged" in reference:
            continue
        r["peak_force_relative_to_reference"] = r["peak_force_N"] / reference["peak_force_N"] - 1
        r["dissipated_energy_relative_to_reference"] = (
            r["dissipated_energy_mJ"] / reference["dissipated_energy_mJ"] - 1
        )
        r["wall_time_ratio_to_reference"] = r["wall_time_s"] / reference["wall_time_s"]

    plot(histories, out / "four_point_bending.png")
    summary = {"units": "N, mm, s, tonne (mJ)", "runs": results}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    script_main(main, PROG)
