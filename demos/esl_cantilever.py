"""# ESL cantilever under a ramped tip load

The first demo of fenics-adaptive: the beam of the paper's triple cantilever beam example
(50 x 2.048 mm, eight 0-degree plies of 0.256 mm, 0.5 mm cells) modelled with ONE solid-shell
element through the thickness (equivalent single layer), clamped at one end and loaded at the other
by a tip force ramped smoothly to 1 N. Explicit dynamics (lumped mass, central differences) with
a little mass damping, so the beam settles on its static deflection.

What to look at: the force-displacement curve follows the beam-theory line, and the final tip
deflection is within about 1.5 % of classical laminate beam theory plus shear deflection, without
shear locking although each cell spans the whole thickness.

Run it (the README's main command does exactly this):

    .venv/bin/python demos/esl_cantilever.py --out results/esl_cantilever

Units: N, mm, s, tonne.
"""

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from fenics_adaptive.analysis.studies import demo_parser
from fenics_adaptive.errors import script_main
from fenics_adaptive.io.output import read_history
from fenics_adaptive.runner import run_config
from fenics_adaptive.settings.config import load_config

HERE = Path(__file__).parent
PROG = "demos/esl_cantilever.py"  # the name its messages and --help give


def beam_theory(config) -> dict:
    """Tip deflection of a cantilever under a tip force P: P L^3 / (3 EI) + P L / (k G13 A), with
    EI of a narrow laminated beam from classical laminate theory and k = 5/6."""
    laminate = config.laminate
    length, width = config.mesh.length, config.mesh.width
    force = abs(config.loads[0].force[2])
    EI = laminate.narrow_beam_bending_stiffness(width)
    G13 = laminate.plies[0].material.G12
    bending = force * length**3 / (3 * EI)
    shear = force * length / (5 / 6 * G13 * width * laminate.thickness)
    return {"force_N": force, "EI_N_mm2": EI, "bending_mm": bending, "total_mm": bending + shear}


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(prog, __doc__, HERE / "esl_cantilever.toml", "results/esl_cantilever")
    args = parser.parse_args(argv)

    # 1. the run itself: the same function the command-line program calls
    config = load_config(args.config)
    out = Path(args.out)
    summary = run_config(config, out, overwrite=args.overwrite)

    # 2. against beam theory
    theory = beam_theory(config)
    history = read_history(out / "history.csv")
    deflection = -history["displacement"][-1]
    error = deflection / theory["total_mm"] - 1
    summary["beam_theory"] = theory | {
        "fe_tip_deflection_mm": deflection,
        "relative_difference": error,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(
        f"tip deflection {deflection:.4f} mm, beam theory {theory['total_mm']:.4f} mm "
        f"(bending {theory['bending_mm']:.4f} + shear): {100 * error:+.2f} %"
    )

    # 3. the picture
    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    ax.plot([-d for d in history["displacement"]], history["reaction_force"], label="ESL, explicit")
    stiffness = theory["force_N"] / theory["total_mm"]
    top = max(-d for d in history["displacement"])
    ax.plot([0, top], [0, stiffness * top], "k--", label="beam theory (CLT + shear)")
    ax.set_xlabel("tip deflection (mm)")
    ax.set_ylabel("clamp reaction force (N)")
    ax.set_title("ESL cantilever, [0]8, one element through the thickness")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.savefig(out / "cantilever_vs_beam_theory.png", dpi=150)
    print(f"plot: {out / 'cantilever_vs_beam_theory.png'}")


if __name__ == "__main__":
    script_main(main, PROG)
