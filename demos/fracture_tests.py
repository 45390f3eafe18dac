"""# Fracture tests: a mode I DCB with an insert film against corrected beam theory

The double cantilever beam (DCB) is how mode I delamination toughness is measured (ASTM D5528).
This demo runs the AS4/PEEK DCB of Camanho, Davila and de Moura (2003) twice:

- ``layerwise``: one cell layer per arm, cohesive elements at the mid-plane interface;
- ``adaptive``: the adaptive element, one cell through the thickness, refined strongly from the
  start at that interface (the automatic indicators are another study's).

Both start from an insert film (``[[delamination]]``): the first 32.9 mm of the interface from
the load line are failed at t = 0, so the crack grows from a sharp front, not from a bonded
end. Each run is compared with corrected beam theory (CBT, Hashemi et al. 1990; ASTM D5528's
modified beam theory): the arms are cantilevers of length a + chi h, chi from the ply's moduli,

    P = 3 E I Delta / (2 (a0 + chi h)^3)              until G = P^2 (a + chi h)^2 / (b E I) = GIc,
    P = (b E I GIc)^(3/4) sqrt(2 / (3 E I Delta))      on the propagation branch,

with Delta the opening of the load line and E I = E1 b h^3 / 12 of one arm.

    .venv/bin/python demos/fracture_tests.py --out results/fracture_tests          # ~4 minutes
    .venv/bin/python demos/fracture_tests.py --out results/fracture_tests --quick  # ~30 s

Writes ``results/fracture_tests/<run>/`` (history.csv, summary.json, plots),
``dcb_force_opening.png`` and ``summary.json`` with the comparisons; it ends by checking them
against the targets below. Units: N, mm, s, tonne.

The runs are quasi-static when the kinetic energy stays a small share of the work put in: the
check asks for less than 5 %.
"""

import argparse
import json
import tomllib
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from fenics_adaptive.analysis.lefm import dcb_comparison, dcb_force
from fenics_adaptive.analysis.studies import DCB_RUNS, dcb_quick, dcb_variant
from fenics_adaptive.errors import script_main
from fenics_adaptive.io.output import read_history
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import parse_config

HERE = Path(__file__).parent
PROG = "demos/fracture_tests.py"  # the name its messages and --help give

# What a DCB run must show against corrected beam theory (fractions)
TARGETS = {
    "peak_over_initiation": 0.05,  # the peak force, within 5 % of the analytic initiation
    "initial_stiffness": 0.05,  # the elastic slope before growth, within 5 %
    "branch_mean": 0.03,  # the force on the propagation branch, mean within 3 %
    "branch_bins": 0.05,  # and every 5 mm bin of crack length within 5 %
    "dissipation_rate": 0.02,  # the energy dissipated per grown area, within 2 % of GIc
    "kinetic_energy_share": 0.05,  # quasi-static: kinetic energy under 5 % of the work put in
}


def run_all(base: dict, out: Path, overwrite: bool = False) -> dict:
    """Run both models; returns {run: (config, summary, history)}."""
    results = {}
    for name in DCB_RUNS:
        config = parse_config(dcb_variant(base, name), source=f"demos/fracture_tests.toml [{name}]")
        print(f"--- DCB, {name}")
        summary, _ = execute(config, out / f"dcb_{name}", overwrite=overwrite)
        results[name] = (config, summary, read_history(out / f"dcb_{name}" / "history.csv"))
    return results


def failures(comparison: dict) -> list[str]:
    """The targets (``TARGETS``) one run's ``dcb_comparison`` misses, in words."""
    c, missed = comparison, []

    def off(value, expected, tolerance, what):
        if value is None or abs(value / expected - 1.0) > tolerance:
            missed.append(f"{what}: {value} against {expected:.6g} (tolerance {tolerance:.0%})")

    off(c["peak_force_N"], c["initiation_force_N"], TARGETS["peak_over_initiation"], "peak force")
    off(c["initial_stiffness_N_per_mm"], c["theory_stiffness_N_per_mm"],
        TARGETS["initial_stiffness"], "initial stiffness")  # fmt: skip
    off(c["force_over_theory_mean"], 1.0, TARGETS["branch_mean"], "propagation force, mean")
    if not c["force_over_theory_bins"]:
        missed.append("the crack did not grow 5 arm thicknesses beyond the film")
    for crack, ratio in c["force_over_theory_bins"].items():
        off(ratio, 1.0, TARGETS["branch_bins"], f"propagation force, crack {crack} mm")
    off(c["dissipation_rate_over_Gc"], 1.0, TARGETS["dissipation_rate"], "dissipation rate")
    share = c["kinetic_energy_share"]
    if share is None or share > TARGETS["kinetic_energy_share"]:
        missed.append(f"kinetic energy share {share} (not quasi-static)")
    return missed


def plot(results: dict, out: Path) -> None:
    """Force against opening of both runs with corrected (and simple) beam theory."""
    fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
    styles = {
        "layerwise": dict(color="k", lw=2.2),
        "adaptive": dict(color="tab:orange", lw=1.2, ls="--"),
    }
    for name, (_, _, h) in results.items():
        ax.plot(2 * np.array(h["displacement"]), h["reaction_force"], label=name, **styles[name])
    config, _, h = results["layerwise"]
    c = dcb_comparison(config, h)
    material = config.laminate.plies[0].material
    opening = np.linspace(0.0, 2 * max(h["displacement"]), 400)
    arm, width, GIc = c["arm_thickness_mm"], config.mesh.width, config.cohesive.GIc
    for crack, label, style in (
        (c["a0_mm"] + c["chi"] * arm, "corrected beam theory", ":"),
        (c["a0_mm"], "simple beam theory", "-."),
    ):
        force = dcb_force(opening, material.E1, width, arm, GIc, crack)
        ax.plot(opening, force, style, color="gray", label=label)
    ax.set_xlabel("load-line opening Delta (mm)")
    ax.set_ylabel("force P (N)")
    ax.set_title(f"DCB, AS4/PEEK, a0 = {c['a0_mm']:g} mm insert film")
    ax.set_ylim(0, None)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.savefig(out / "dcb_force_opening.png", dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0].lstrip("# "))
    parser.add_argument("--config", default=HERE / "fracture_tests.toml")
    parser.add_argument("--out", default="results/fracture_tests")
    parser.add_argument("--quick", action="store_true", help="a shorter DCB, for a fast look")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="reuse run folders that hold other files (only this program's own files go)",
    )
    args = parser.parse_args(argv)
    base = tomllib.loads(Path(args.config).read_text())
    if args.quick:
        base = dcb_quick(base)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    results = run_all(base, out, args.overwrite)
    comparisons = {name: dcb_comparison(config, h) for name, (config, _, h) in results.items()}
    plot(results, out)
    F = {name: np.array(h["reaction_force"]) for name, (_, _, h) in results.items()}
    summary = {
        "units": "N, mm, s, tonne (mJ)",
        "dcb": comparisons,
        "dcb_adaptive_against_layerwise_max_force_difference_N": float(
            np.abs(F["adaptive"] - F["layerwise"]).max()
        ),
        "wall_time_s": {name: s["wall_time_s"] for name, (_, s, _) in results.items()},
        "targets": TARGETS,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    missed = [f"DCB {name}: {line}" for name, c in comparisons.items() for line in failures(c)]
    if missed:
        raise SystemExit("targets missed:\n  " + "\n  ".join(missed))
    print("every target met")


if __name__ == "__main__":
    script_main(main, PROG)
