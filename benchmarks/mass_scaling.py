"""Selective mass scaling: what it buys and what it changes (issue 17, item 5).

    .venv/bin/python benchmarks/mass_scaling.py            # about 3 min on 2 vCPUs
    .venv/bin/python benchmarks/mass_scaling.py --quick    # about 1 min

Three measurements, written as a Markdown table to ``benchmarks/results/mass_scaling.md``
(``docs/mass_scaling.md`` includes it):

1. **Bending frequencies.** A [0/90/0/90]s plate 20 x 20 mm clamped on its four edges, 10 x 10
   cells, of two thicknesses: the lowest three frequencies with the lumped and the scaled mass
   (dense eigenvalue problems K x = omega^2 M x on the free DOFs, K column by column from the
   internal force), the highest frequency of each, and the factors.
2. **The price: through-thickness waves.** A thickness-stretch mode of an element is
   sqrt(1 + s_n) slower with the scaled mass (its relative mass grows by 1 + s_n): a wave
   through the thickness, resolved by a few elements, is slower by about as much; the plates'
   largest s_n gives the factor.
3. **The TCB.** The layerwise TCB of ``tests/data/tcb_layerwise.toml`` with one mesh layer per
   ply of 0.064 mm, and the ESL model of the same beam, each with the lumped and the scaled
   mass at its own stable step: the step, the wall time, the peak force and the dissipated
   energy against the unscaled layerwise run.

Units: N, mm, s, tonne (frequencies in Hz).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import mpi4py  # noqa: F401  (before dolfinx)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fenics_adaptive.meshes import esl_mesh  # noqa: E402

from fenics_adaptive.analysis.vibration import dense_system, frequencies  # noqa: E402
from fenics_adaptive.io.output import read_history  # noqa: E402
from fenics_adaptive.materials.laminate import Laminate, PlyMaterial  # noqa: E402
from fenics_adaptive.model import loading  # noqa: E402
from fenics_adaptive.model.forms import build_model  # noqa: E402
from fenics_adaptive.model.mass_scaling import selective_mass  # noqa: E402
from fenics_adaptive.model.structure import Structure  # noqa: E402
from fenics_adaptive.runner import run_config  # noqa: E402
from fenics_adaptive.settings.config import parse_config  # noqa: E402
from fenics_adaptive.settings.loads import clamp  # noqa: E402

PLY = PlyMaterial(
    "prototype", E1=100e3, E2=10e3, G12=5e3, G23=4e3, nu12=0.25, nu23=0.25, rho=1.6e-9
)


def clamped_plate(ply_thickness: float, cells: int) -> Structure:
    """The [0/90/0/90]s plate 20 x 20 mm of ``cells`` x ``cells``, clamped on its edges."""
    from mpi4py import MPI

    laminate = Laminate.from_angles(PLY, [0, 90, 0, 90, 90, 0, 90, 0], ply_thickness)
    beam = esl_mesh(MPI.COMM_WORLD, 20.0, 20.0, cells, cells, laminate.thickness)
    model = build_model(beam, [laminate])
    motions = [m for face in ("x0", "x1", "y0", "y1") for m in clamp(face)]
    return Structure(model, loading.resolve(model, motions, []))


def plate_rows(quick: bool) -> list[str]:
    rows = []
    for ply in (0.05,) if quick else (0.05, 0.025):
        structure = clamped_plate(ply, 10)
        structure.scaled_mass = selective_mass(structure)
        K, lumped, scaled = dense_system(structure)
        f_l, f_s = frequencies(K, lumped), frequencies(K, scaled)
        mass = structure.scaled_mass
        ratio = f_s[:3] / f_l[:3] - 1.0
        rows.append(
            f"| plate {8 * ply:.2f} mm, 2 mm cells | "
            + ", ".join(f"{f:.0f}" for f in f_l[:3])
            + " | "
            + ", ".join(f"{100 * r:+.2f} %" for r in ratio)
            + f" | {f_l[-1] / f_s[-1]:.2f} x | s_n {mass.normal_scaling.max():.1f}, "
            f"s_t {mass.shear_scaling.max():.2f} | "
            f"through-thickness waves {math.sqrt(1 + mass.normal_scaling.max()):.2f} x slower |"
        )
    return rows


def tcb_data(kind: str, scaling: str, end_time: float) -> dict:
    text = (ROOT / "tests" / "data" / "tcb_layerwise.toml").read_text()
    for old, new in (
        ("time_step = 4.0e-8", ""),
        ("layers = [2, 2, 2, 2]", "layers = [1, 1, 1, 1, 1, 1, 1, 1]"),
        ("ply_thickness = 0.256", "ply_thickness = 0.064"),
    ):
        text = text.replace(old, new)
    data = tomllib.loads(text)
    data["solver"].update(end_time=end_time, mass_scaling=scaling)
    data["output"].pop("fields_interval", None)
    if kind == "esl":
        data["model"]["kind"] = "esl"
        data["mesh"].pop("layers")
        for name in ("interfaces", "cohesive"):
            data.pop(name)
    return data


def tcb_rows(quick: bool, folder: Path) -> list[str]:
    end_time = 1.0e-4 if quick else 4.0e-4
    results = {}
    for kind in ("layerwise", "esl"):
        for scaling in ("none", "selective"):
            out = folder / f"tcb_{kind}_{scaling}"
            start = time.perf_counter()
            summary = run_config(
                parse_config(tcb_data(kind, scaling, end_time)), out, show_progress=False, log=None
            )
            wall = time.perf_counter() - start
            history = read_history(out / "history.csv")
            results[kind, scaling] = (summary["time_step"], wall, history)
    reference = results["layerwise", "none"][2]
    peak = max(reference["reaction_force"])
    rows = []
    for (kind, scaling), (step, wall, history) in results.items():
        force = np.asarray(history["reaction_force"])
        dissipated = history["dissipated_energy"][-1]
        against = reference["dissipated_energy"][-1]
        if kind == "esl":  # no cohesive elements: it cannot delaminate, nothing to compare
            errors = "- (cannot delaminate) | - |"
        else:
            errors = (
                f"{100 * (force.max() / peak - 1):+.2f} % | "
                f"{100 * (dissipated / against - 1):+.2f} % |"
            )
        rows.append(
            f"| TCB {kind}, {scaling} | {step['used_s']:.3g} s ({step['limited_by']}) | "
            f"{wall:.1f} s | {errors}"
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plate = plate_rows(args.quick)
    with tempfile.TemporaryDirectory() as runs:
        tcb = tcb_rows(args.quick, Path(runs))
    text = "\n".join(
        [
            "| plate | lowest three frequencies, lumped (Hz) | scaled against lumped | "
            "critical step, scaled / lumped | factors | the price |",
            "|---|---|---|---|---|---|",
            *plate,
            "",
            "| run | step (limited by) | wall time | peak force against LW unscaled | "
            "dissipated energy against LW unscaled |",
            "|---|---|---|---|---|",
            *tcb,
            "",
        ]
    )
    print(text)
    (out / ("mass_scaling_quick.md" if args.quick else "mass_scaling.md")).write_text(text)


if __name__ == "__main__":
    main()
