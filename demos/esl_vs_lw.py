"""# ESL or layerwise? Interlaminar stresses of a short laminated cantilever

When is one solid-shell element through the thickness (equivalent single layer, ESL) enough, and
when does a laminate need the through-thickness refinement of the adaptive element, or a
layerwise (LW) model? This demo answers it for one bending case, three layups and four models,
with numbers: deflection, in-plane stress, interlaminar (out-of-plane) stresses at the ply
interfaces, and the cost of an explicit step.

## The case

A cantilever 20 mm long, 2 mm wide and 2 mm thick (eight 0.25 mm plies; span/thickness 10, so
transverse shear matters), clamped at x = 0 (every node of that end held), loaded by a uniform
pressure on its top face (10 N in total, 0.25 MPa). Three layups: ``[0]8``, the cross-ply
``[0/90]2s`` and the quasi-isotropic ``[0/45/-45/90]s``. 0.5 mm cells in-plane, the same in every
model. All loads and supports act on nodes every model has (top face, clamped end), so the
models differ only in their through-thickness description. Stresses are compared at mid-span
(x = 10 +- 1 mm, averaged over the width; the beam is narrow, with free sides), where the shear
force is V = q L / 2 and clamp and tip are four thicknesses or more away.

## The four models

- **(a) ESL, constitutive**: one element through the thickness (the unrefined adaptive element:
  layered integration, each ply's stiffness at its own points). Interlaminar stresses as the
  element computes them, C_k * strain in each ply: its transverse shear strain is constant
  through the thickness, so tau_xz is constant within each ply and jumps with the ply's shear
  modulus; its sigma_zz comes from the thickness strain (compatible plus enhanced) and Poisson
  coupling, not from the load.
  Values at an interface: the mean of the two plies (what a post-processor shows).
- **(b) ESL, recovered**: the same solution, the out-of-plane stresses recovered from
  equilibrium (``indicators.recovered_interface_stresses``, what the strong-refinement
  indicator uses): the plies' in-plane stresses are differentiated in-plane and
  d tau/dz = -div(sigma) integrated from the free bottom face; once more for sigma_zz.
- **(c) refined**: the adaptive element refined weakly at all seven interfaces from the start
  (``[interfaces] refine = [1..7]``, ``initial = "weak"``): extra nodes at every interface,
  one subelement per ply, computed by the numba kernel.
- **(d) LW**: the layerwise reference, one cell layer per ply (``mesh.layers = [1]*8``).
  It is the reference of every error below.

For (c) and (d), which have nodes at the interfaces, the interlaminar stress is the traction
the interface transmits (``comparison.interface_tractions``): the internal force of the elements
above the interface on its nodes per unit area, i.e. what a cohesive element there would carry.
It follows from the discrete equilibrium alone, with no recovery formula shared with (b).

## How the static answers are obtained

Linear statics, solved directly: the package's static solver (``static.solve_static``) knows
only the UFL cells of the base model, not extra nodes, so ``comparison.solve_linear_static``
probes the stiffness matrix out of the package's own internal force (``Structure.internal_force``,
exactly what the explicit solver integrates: with a distance-2 node colouring, one force
evaluation per colour and component, 50-110 here) and solves it with PETSc LU. Honesty checks,
all in ``summary.json``: the residual |f_ext - f_int(u)| / |f_ext| with the package's force
(about 1e-11), the reaction at the clamp against the applied load, 1/2 f.u against the strain
energy. For ESL and LW the same answer also comes out of ``static.solve_static`` (checked in
``tests/test_esl_vs_lw.py``), and the refined model is additionally run through the explicit
solver quasi-statically (smooth load ramp over 1.5 periods of the first bending mode, mass
damping critical on that mode, 4 periods in all, about 22 000 steps) to show that the path a
user runs reaches the same deflection (``explicit_check`` in the summary).

## Cost

Measured, serial, on this machine: the wall time of one explicit step (central differences,
lumped mass; the best of 5 runs of 300 steps at the model's stable time step, timed by the
solver's own clock, after a warm-up run so that numba and FFCx compilation is excluded) and of
one internal-force evaluation (the best of 50; best, not mean, because other load on the machine
only ever adds time). The one-ply cells of (c) and (d) also halve the
stable time step, so the cost of simulating a given time is the time per step divided by the
time step: ``wall_s_per_simulated_ms``, and ``cost_vs_esl`` relative to (a). (b) costs what (a)
costs per step, plus one recovery whenever the indicators run (``recovery_ms``). On a model this
small a good part of a step is fixed overhead (vector updates, scatters), so the ratios
understate what larger models show.

## How to read the results

``esl_vs_lw.csv`` in the output folder (and the table printed at the end; the first CSV line
states the units): per layup and model the tip deflection, the largest in-plane stress
difference over the ply mid-points and the largest interlaminar stress differences over the
seven interfaces, all relative to LW (stress errors in % of the LW peak of that component over
the interfaces; tau_yz in % of the tau_xz peak), the same against laminated beam theory, and the
cost. ``esl_vs_lw.png``: tau_xz and sigma_zz through the thickness for every model and layup with
beam theory (grey), the largest errors against LW in each panel's title, and the errors and
costs as bars. ``summary.json``: all of it, with the through-thickness values, the static
solutions' checks and the explicit check.

What it shows:

- deflection and in-plane stresses: the ESL element is within about 1.5 % of LW (a little
  too stiff: its transverse shear strain is constant through the thickness, with no shear
  correction);
- interlaminar stresses, constitutive (a): tau_xz is constant within each ply, each ply's the
  laminate's mean over it (``materials.laminate.ply_shear_factors``), so the interfaces read
  the plies' means, and sigma_zz, made by the thickness strain and Poisson coupling
  rather than by the load, is off by 40-50 % of its peak (by more than its own size, with the
  wrong sign in the upper plies, with the compatible thickness strain alone);
- recovered from equilibrium (b): within about 2 % of LW at every interface for all three
  layups, for the price of one recovery per indicator check;
- the refined element (c) equals LW (to round-off: the paper's "matches the reference"), at
  about LW's cost per step (both go through the same element kernel), with the two-fold
  smaller stable time step it shares with LW.

So for a laminate in bending, ESL with recovered out-of-plane stresses is enough to see where
interlaminar stresses become critical (which is what the strong-refinement indicator needs);
refine (or go layerwise) where the through-thickness fields themselves matter: delamination
onset and growth, ply failure near interfaces. The adaptive element pays off when only a few
cells need that.

Run it (serial; about 1.5 minutes on a 2-core machine):

    .venv/bin/python demos/esl_vs_lw.py --out results/esl_vs_lw

Units: N, mm, s, tonne (stress MPa, energy mJ).
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import platform
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import matplotlib
import numpy as np
from mpi4py import MPI

matplotlib.use("Agg")
import dolfinx
import matplotlib.pyplot as plt

import fenics_adaptive
from fenics_adaptive.adaptivity.indicators import recovered_interface_stresses
from fenics_adaptive.analysis import comparison as cmp
from fenics_adaptive.analysis.studies import demo_parser
from fenics_adaptive.analysis.timing import time_call, time_per_step
from fenics_adaptive.errors import script_main
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.config import RunConfig, parse_config
from fenics_adaptive.settings.loads import Amplitude
from fenics_adaptive.settings.solver import SolverSettings
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

HERE = Path(__file__).parent
PROG = "demos/esl_vs_lw.py"  # the name its messages and --help give
MODELS = {
    "esl_constitutive": "(a) ESL, constitutive",
    "esl_recovered": "(b) ESL, recovered",
    "refined": "(c) refined (weak, all interfaces)",
    "layerwise": "(d) LW reference",
}
REFERENCE = "layerwise"


# ----------------------------------------------------------------------------- configuration
def load_settings(path: str | Path) -> dict:
    """The demo's TOML (see demos/esl_vs_lw.toml)."""
    return tomllib.loads(Path(path).read_text())


def run_config(settings: dict, angles: list[float], kind: str) -> RunConfig:
    """The run config of one model (kind "esl", "adaptive" = refined, "layerwise") of a layup,
    checked by the package's parser. The explicit-solver sections only matter for timing."""
    beam = settings["beam"]
    n = len(angles)
    data = {
        "model": {"kind": kind, "points_per_ply": beam["points_per_ply"]},
        "mesh": {k: beam[k] for k in ("length", "width", "nx", "ny")},
        "materials": copy.deepcopy(settings["materials"]),
        "laminate": {
            "material": next(iter(settings["materials"])),
            "ply_thickness": beam["ply_thickness"],
            "angles": list(angles),
        },
        "clamp": [{"face": "x0"}],
        # applied at full size from t = 0: a static load (the explicit check ramps it)
        "load": [{"face": "top", "force": [0.0, 0.0, -beam["load"]], "curve": [[0.0, 1.0]]}],
        "solver": {"end_time": 1.0e-6},
        "output": {
            "interval": 1.0e-6,
            "displacement_face": "x1",
            "reaction_face": "x0",
            "component": "z",
        },
    }
    if kind == "adaptive":
        data["interfaces"] = {"refine": list(range(1, n)), "initial": "weak"}
    if kind == "layerwise":
        data["mesh"]["layers"] = [1] * n
    return parse_config(data, source=f"demos/esl_vs_lw.toml [{kind}]")


def beam_theory(settings: dict, config: RunConfig) -> cmp.CantileverBeamTheory:
    beam = settings["beam"]
    return cmp.CantileverBeamTheory(config.laminate, beam["length"], beam["width"], beam["load"])


# ----------------------------------------------------------------------------- one layup
def _near(x: np.ndarray, settings: dict) -> np.ndarray:
    """Sample points (cell centres or node lines) of the comparison section."""
    section = settings["section"]
    return np.abs(x - section["x"]) <= section["half_width"] + 1e-9 * settings["beam"]["length"]


def measure_cost(structure: Structure, config: RunConfig, settings: dict) -> dict:
    timing = settings["timing"]
    per_force, _ = time_call(structure.internal_force, timing["force_repeats"], warmups=3)
    per_step, dt = time_per_step(structure, config.probe, timing["steps"], timing["repeats"])
    return {
        "time_per_step_s": per_step,
        "time_per_force_s": per_force,
        "stable_time_step_s": dt,
        "wall_time_per_simulated_ms_s": per_step / dt * 1e-3,
    }


def analyse_model(settings: dict, angles: list[float], kind: str) -> dict:
    """Static solution of one model and what it says at the section; then its cost."""
    config = run_config(settings, angles, kind)
    structure = build_structure(config)
    static = cmp.solve_linear_static(structure)
    stresses, centroids = cmp.column_ply_stresses(structure)
    cells = _near(centroids[:, 0], settings)
    out = {
        "config": config,
        "static": static.summary(),
        "tip_deflection_mm": cmp.tip_deflection(structure),
        "cell_x": centroids[cells, 0],
        "ply_stresses": stresses[cells].mean(axis=0),  # (n_plies, 6) at the ply mid-points
        "constitutive_at_interfaces": cmp.ply_values_at_interfaces(stresses)[cells].mean(axis=0),
    }
    if kind == "esl":
        recovered_interface_stresses(structure)  # warm-up: numba loads its compiled kernels
        start = time.perf_counter()
        recovered = recovered_interface_stresses(structure)
        out["recovery_s"] = time.perf_counter() - start
        out["recovered_at_interfaces"] = recovered[cells].mean(axis=0)
    else:
        tractions = cmp.interface_tractions(structure)
        values = np.full((len(angles) + 1, 3), np.nan)
        for interface, (x, v) in tractions.items():
            values[interface] = v[_near(x, settings)].mean(axis=0)
        out["tractions_at_interfaces"] = values
        out["line_x"] = tractions[1][0][_near(tractions[1][0], settings)]
    out["cost"] = measure_cost(structure, config, settings)
    return out


def _relative(value: np.ndarray, reference: np.ndarray, scale: float) -> float:
    """Largest |value - reference| in units of ``scale``."""
    return float(np.nanmax(np.abs(np.asarray(value) - np.asarray(reference))) / scale)


def analyse_layup(settings: dict, name: str, angles: list[float]) -> dict:
    """The four models of one layup, their errors against LW and beam theory."""
    print(f"--- {name}")
    runs = {
        kind: analyse_model(settings, angles, kind) for kind in ("esl", "adaptive", "layerwise")
    }
    theory = beam_theory(settings, runs["esl"]["config"])
    lw = runs["layerwise"]
    inner = slice(1, len(angles))  # the seven interfaces (the faces are known: free, or loaded)
    # each model at the interfaces: (sigma_zz, tau_xz, tau_yz), (n_plies + 1, 3)
    at_interfaces = {
        "esl_constitutive": runs["esl"]["constitutive_at_interfaces"],
        "esl_recovered": runs["esl"]["recovered_at_interfaces"],
        "refined": runs["adaptive"]["tractions_at_interfaces"],
        "layerwise": lw["tractions_at_interfaces"],
    }
    run_of = {
        "esl_constitutive": "esl",
        "esl_recovered": "esl",
        "refined": "adaptive",
        "layerwise": "layerwise",
    }
    # beam theory averaged over the same sample points as each model: cell centres (ESL, and
    # every model's ply stresses) or node lines (interface tractions)
    exact_at = {
        "cells": theory.out_of_plane(runs["esl"]["cell_x"]),
        "lines": theory.out_of_plane(lw["line_x"]),
    }
    exact_interfaces = exact_at["lines"]
    exact_plies = theory.ply_in_plane(runs["esl"]["cell_x"])
    exact_tip = theory.tip_deflection()

    lw_stress = at_interfaces[REFERENCE][inner]
    peak_tau = np.abs(lw_stress[:, 1]).max()
    peak_zz = np.abs(lw_stress[:, 0]).max()
    lw_sxx = lw["ply_stresses"][:, 0]
    models = {}
    for model, label in MODELS.items():
        run = runs[run_of[model]]
        values = at_interfaces[model][inner]
        exact = exact_at["cells" if run_of[model] == "esl" else "lines"]
        sxx = run["ply_stresses"][:, 0]
        cost = dict(run["cost"])
        if model == "esl_recovered":
            cost["recovery_ms"] = 1e3 * run["recovery_s"]
        models[model] = {
            "label": label,
            "dofs": run["static"]["dofs"],
            "tip_deflection_mm": run["tip_deflection_mm"],
            "errors_vs_lw": {
                "tip_deflection": run["tip_deflection_mm"] / lw["tip_deflection_mm"] - 1.0,
                "sigma_xx_plies": _relative(sxx, lw_sxx, np.abs(lw_sxx).max()),
                "tau_xz_interfaces": _relative(values[:, 1], lw_stress[:, 1], peak_tau),
                "sigma_zz_interfaces": _relative(values[:, 0], lw_stress[:, 0], peak_zz),
                "tau_yz_interfaces": _relative(values[:, 2], lw_stress[:, 2], peak_tau),
            },
            "errors_vs_beam_theory": {
                "tip_deflection": run["tip_deflection_mm"] / exact_tip["total_mm"] - 1.0,
                "sigma_xx_plies": _relative(
                    sxx, exact_plies[:, 0], np.abs(exact_plies[:, 0]).max()
                ),
                "tau_xz_interfaces": _relative(
                    values[:, 1], exact[inner, 1], np.abs(exact[inner, 1]).max()
                ),
                "sigma_zz_interfaces": _relative(
                    values[:, 0], exact[inner, 0], np.abs(exact[inner, 0]).max()
                ),
            },
            # null where a model has no value: the faces of (c) and (d), where the interface
            # traction is the boundary condition, not a result
            "at_interfaces": {
                c: [None if math.isnan(v) else float(v) for v in at_interfaces[model][:, k]]
                for k, c in enumerate(cmp.OUT_OF_PLANE)
            },
            "ply_mid_points": {
                "sigma_xx": sxx.tolist(),
                **{
                    c: run["ply_stresses"][:, v].tolist()
                    for c, v in zip(cmp.OUT_OF_PLANE, cmp.VOIGT_OUT_OF_PLANE, strict=True)
                },
            },
            "cost": cost,
            "static_solution": run["static"],
        }
    laminate = runs["esl"]["config"].laminate
    z = laminate.ply_fractions * laminate.thickness - 0.5 * laminate.thickness
    z_fine = np.linspace(z[0], z[-1], 161)
    return {
        "angles": list(angles),
        "case": {**settings["beam"], "thickness": laminate.thickness},
        "z_interfaces_mm": z.tolist(),
        "section_x_mm": settings["section"]["x"],
        "beam_theory": {
            "tip_deflection": exact_tip,
            "EI_N_mm2": theory.EI,
            "shear_compliance_per_N": theory.shear_compliance(),
            "at_interfaces": {
                c: exact_interfaces[:, k].tolist() for k, c in enumerate(cmp.OUT_OF_PLANE)
            },
            "sigma_xx_plies": exact_plies[:, 0].tolist(),
            "profile": {
                "z_mm": z_fine.tolist(),
                **{
                    c: theory.out_of_plane(settings["section"]["x"], z_fine)[:, k].tolist()
                    for k, c in enumerate(cmp.OUT_OF_PLANE)
                },
            },
        },
        "models": models,
    }


# ----------------------------------------------------------------------------- explicit check
def explicit_check(settings: dict, static_tip: float) -> dict:
    """The refined model of one layup through the package's explicit solver: load ramped
    smoothly over ``ramp_periods`` first-mode periods, mass damping 2 zeta omega_1, run for
    ``end_periods``; its final deflection against the static one."""
    check = settings["explicit_check"]
    base = run_config(settings, settings["layups"][check["layup"]], "adaptive")
    period = cmp.first_bending_period(beam_theory(settings, base))
    omega = 2.0 * math.pi / period
    end_time = check["end_periods"] * period
    load = base.loads[0]
    ramped = dataclasses.replace(load, amplitude=Amplitude.ramp(check["ramp_periods"] * period))
    solver = SolverSettings(
        end_time=end_time,
        output_interval=end_time / 200,
        mass_damping=2.0 * check["damping_ratio"] * omega,
    )
    config = dataclasses.replace(base, loads=(ramped,), solver=solver)
    structure = build_structure(config)
    stats = explicit.run(structure, config.solver, config.probe)
    rows = stats.history
    work = max(abs(r.external_work) for r in rows)
    tip = cmp.tip_deflection(structure)
    return {
        "layup": check["layup"],
        "model": MODELS["refined"],
        "first_bending_period_s": period,
        "mass_damping_per_s": solver.mass_damping,
        "end_time_s": end_time,
        "steps": stats.steps,
        "wall_time_s": stats.wall_time,
        "time_per_step_s": stats.wall_time / max(stats.steps, 1),
        "tip_deflection_mm": tip,
        "static_tip_deflection_mm": static_tip,
        "relative_difference": tip / static_tip - 1.0,
        "final_relative_residual": cmp.equilibrium_residual(structure, end_time),
        "final_kinetic_over_work": rows[-1].kinetic_energy / work,
        "max_energy_balance_error_over_work": max(abs(r.energy_balance) for r in rows) / work,
    }


# ----------------------------------------------------------------------------- output
COLUMNS = [
    ("layup", None, None),
    ("model", None, None),
    ("description", None, None),
    ("dofs", None, None),
    ("tip_deflection_mm", None, None),
    ("deflection_err_vs_lw_pct", "errors_vs_lw", "tip_deflection"),
    ("sigma_xx_err_vs_lw_pct", "errors_vs_lw", "sigma_xx_plies"),
    ("tau_xz_err_vs_lw_pct", "errors_vs_lw", "tau_xz_interfaces"),
    ("sigma_zz_err_vs_lw_pct", "errors_vs_lw", "sigma_zz_interfaces"),
    ("tau_yz_err_vs_lw_pct_of_tau_xz", "errors_vs_lw", "tau_yz_interfaces"),
    ("deflection_err_vs_theory_pct", "errors_vs_beam_theory", "tip_deflection"),
    ("tau_xz_err_vs_theory_pct", "errors_vs_beam_theory", "tau_xz_interfaces"),
    ("sigma_zz_err_vs_theory_pct", "errors_vs_beam_theory", "sigma_zz_interfaces"),
    ("stable_time_step_ns", "cost", "stable_time_step_s"),
    ("time_per_step_us", "cost", "time_per_step_s"),
    ("time_per_force_us", "cost", "time_per_force_s"),
    ("wall_s_per_simulated_ms", "cost", "wall_time_per_simulated_ms_s"),
    ("cost_vs_esl", None, None),
    ("recovery_ms", "cost", "recovery_ms"),
]


def table_rows(results: dict) -> list[dict]:
    """One row per layup and model (the CSV and the printed table)."""
    rows = []
    for layup, result in results.items():
        esl_cost = result["models"]["esl_constitutive"]["cost"]["wall_time_per_simulated_ms_s"]
        for model, entry in result["models"].items():
            row = {
                "layup": layup,
                "model": model,
                "description": entry["label"],
                "dofs": entry["dofs"],
                "tip_deflection_mm": entry["tip_deflection_mm"],
            }
            for name, group, key in COLUMNS:
                if group is None:
                    continue
                value = entry[group].get(key)
                if value is None:
                    row[name] = ""
                elif name.endswith("_pct") or name.endswith("_pct_of_tau_xz"):
                    row[name] = 100.0 * value
                elif name.endswith("_ns"):
                    row[name] = 1e9 * value
                elif name.endswith("_us"):
                    row[name] = 1e6 * value
                else:
                    row[name] = value
            row["cost_vs_esl"] = entry["cost"]["wall_time_per_simulated_ms_s"] / esl_cost
            rows.append(row)
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["# units: N, mm, s, tonne; stresses MPa; errors in %; times as named"])
        writer.writerow([name for name, _, _ in COLUMNS])
        for row in rows:
            writer.writerow(
                [
                    f"{row[name]:.6g}" if isinstance(row[name], float) else row[name]
                    for name, _, _ in COLUMNS
                ]
            )


def print_table(rows: list[dict]) -> None:
    head = (
        f"{'layup':<16}{'model':<36}{'w_tip mm':>9}{'dw %':>7}{'sxx %':>7}{'txz %':>7}"
        f"{'szz %':>7}{'tyz %':>7}{'txz-BT %':>9}{'dt ns':>7}{'us/step':>9}{'cost':>6}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        print(
            f"{r['layup']:<16}{r['description']:<36}{r['tip_deflection_mm']:>9.5f}"
            f"{r['deflection_err_vs_lw_pct']:>7.2f}{r['sigma_xx_err_vs_lw_pct']:>7.2f}"
            f"{r['tau_xz_err_vs_lw_pct']:>7.1f}{r['sigma_zz_err_vs_lw_pct']:>7.1f}"
            f"{r['tau_yz_err_vs_lw_pct_of_tau_xz']:>7.1f}{r['tau_xz_err_vs_theory_pct']:>9.1f}"
            f"{r['stable_time_step_ns']:>7.1f}{r['time_per_step_us']:>9.0f}{r['cost_vs_esl']:>6.2f}"
        )
    print(
        "errors vs LW (d): deflection; largest over plies (sxx) or interfaces, in % of the LW "
        "peak of that stress (tyz: of the txz peak); txz-BT: vs laminated beam theory; cost: "
        "wall time per simulated ms relative to ESL"
    )


STYLE = {
    "esl_constitutive": dict(color="tab:red", ls="-", lw=1.2),
    "esl_recovered": dict(color="tab:blue", marker="o", ms=5, ls="-", lw=1.2),
    "refined": dict(color="tab:orange", marker="s", ms=8, mfc="none", ls="none", mew=1.5),
    "layerwise": dict(color="k", marker="x", ms=6, ls="--", lw=1.0),
}


def plot(results: dict, path: Path) -> None:
    """tau_xz and sigma_zz through the thickness per layup; errors and cost as bars."""
    layups = list(results)
    fig, axes = plt.subplots(3, len(layups), figsize=(4.6 * len(layups), 12), layout="constrained")
    axes = np.atleast_2d(axes).reshape(3, len(layups))
    for col, layup in enumerate(layups):
        result = results[layup]
        z = np.array(result["z_interfaces_mm"])
        profile = result["beam_theory"]["profile"]
        for row, (component, label) in enumerate(
            (("tau_xz", "tau_xz (MPa)"), ("sigma_zz", "sigma_zz (MPa)"))
        ):
            ax = axes[row, col]
            ax.plot(
                profile[component],
                profile["z_mm"],
                color="0.6",
                lw=4,
                alpha=0.6,
                label="beam theory",
            )
            errors = []
            for model, entry in result["models"].items():
                style = STYLE[model]
                if model == "esl_constitutive":
                    ply = np.array(entry["ply_mid_points"][component])
                    ax.stairs(ply, z, orientation="horizontal", baseline=None, **style)
                else:
                    values = np.array(entry["at_interfaces"][component], dtype=float)
                    keep = np.isfinite(values)
                    ax.plot(values[keep], z[keep], **style)
                if model != REFERENCE:
                    err = 100 * entry["errors_vs_lw"][f"{component}_interfaces"]
                    errors.append(f"{entry['label'][:3]} {err:.1f} %")
            for zi in z[1:-1]:
                ax.axhline(zi, color="0.85", lw=0.5, zorder=0)
            ax.set_xlabel(label)
            ax.set_ylabel("z from mid-plane (mm)")
            ax.set_title(
                f"{layup}: {component} at x = {result['section_x_mm']:g} mm\n"
                f"max error vs LW: {', '.join(errors)}",
                fontsize=9,
            )
    # one legend for all profiles (the same models everywhere)
    handles = [plt.Line2D([], [], color="0.6", lw=4, alpha=0.6, label="beam theory")]
    for model, label in MODELS.items():
        handles.append(plt.Line2D([], [], label=label, **STYLE[model]))
    beam = results[layups[0]]["case"]
    fig.legend(
        handles=handles,
        loc="outside upper center",
        ncol=5,
        fontsize=8,
        title=(
            f"ESL vs LW: cantilever {beam['length']:g} x {beam['width']:g} x "
            f"{beam['thickness']:g} mm, {beam['load']:g} N uniform on the top face; "
            "stresses in MPa, errors relative to the LW reference"
        ),
        title_fontsize=11,
    )
    # bars: errors vs LW and cost, one group of four per layup
    width = 0.2
    x = np.arange(len(layups))
    bars = (
        ("tau_xz at the interfaces: max error vs LW (% of peak)", "%.1f"),
        ("tip deflection: |error| vs LW (%)", "%.2f"),
        ("time per explicit step (us); labels: cost per\nsimulated time relative to ESL", None),
    )
    for k, model in enumerate(MODELS):
        entries = [results[lay]["models"][model] for lay in layups]
        heights = (
            [100 * e["errors_vs_lw"]["tau_xz_interfaces"] for e in entries],
            [100 * abs(e["errors_vs_lw"]["tip_deflection"]) for e in entries],
            [1e6 * e["cost"]["time_per_step_s"] for e in entries],
        )
        relative = [
            e["cost"]["wall_time_per_simulated_ms_s"]
            / results[lay]["models"]["esl_constitutive"]["cost"]["wall_time_per_simulated_ms_s"]
            for e, lay in zip(entries, layups, strict=True)
        ]
        for ax, h, (_, fmt) in zip(axes[2], heights, bars, strict=False):
            drawn = ax.bar(x + (k - 1.5) * width, h, width, color=STYLE[model]["color"])
            drawn.set_label(MODELS[model])
            if fmt is None:
                ax.bar_label(drawn, labels=[f"{r:.1f}x" for r in relative], fontsize=7)
            else:
                ax.bar_label(drawn, fmt=fmt, fontsize=6)
    for ax, (title, _) in zip(axes[2], bars, strict=False):
        ax.set_xticks(x, layups, fontsize=8)
        ax.set_title(title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.margins(y=0.15)
    axes[2, 0].legend(fontsize=7)
    fig.savefig(path, dpi=130)
    plt.close(fig)


# ----------------------------------------------------------------------------- main
def run(settings: dict, out: Path, log: Callable[[str], None] = print) -> dict:
    """Everything: every layup, the explicit check, the files; returns the summary."""
    start = time.perf_counter()
    results = {
        name: analyse_layup(settings, name, angles) for name, angles in settings["layups"].items()
    }
    summary = {
        "units": "N, mm, s, tonne (stress MPa, energy mJ)",
        "case": {
            **settings["beam"],
            "section": settings["section"],
            "loading": "uniform pressure on the top face, clamped end x = 0",
        },
        "models": MODELS,
        "reference": MODELS[REFERENCE],
        "static_solution": "stiffness probed from Structure.internal_force (distance-2 node "
        "colouring), PETSc LU; residual with the package's force in static_solution",
        "cost_measurement": "serial; best of timing.repeats explicit.run calls of timing.steps "
        "steps at the stable time step after a warm-up run (compilation excluded), the solver's "
        "own clock; time_per_force: best of timing.force_repeats Structure.internal_force calls",
        "layups": results,
        "mpi_ranks": MPI.COMM_WORLD.size,
        "versions": {
            "fenics_adaptive": fenics_adaptive.__version__,
            "dolfinx": dolfinx.__version__,
            "python": platform.python_version(),
        },
    }
    check = settings.get("explicit_check", {})
    if check.get("enabled", False):
        layup = check["layup"]
        static_tip = results[layup]["models"]["refined"]["tip_deflection_mm"]
        log(f"--- explicit quasi-static check: {MODELS['refined']}, {layup}")
        summary["explicit_check"] = explicit_check(settings, static_tip)
    out.mkdir(parents=True, exist_ok=True)
    rows = table_rows(results)
    write_csv(rows, out / "esl_vs_lw.csv")
    plot(results, out / "esl_vs_lw.png")
    summary["wall_time_s"] = time.perf_counter() - start
    text = json.dumps(summary, indent=2, default=_json, allow_nan=False)
    (out / "summary.json").write_text(text + "\n")
    print_table(rows)
    return summary


def _json(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def main(argv: list[str] | None = None, prog: str = PROG) -> None:
    parser = demo_parser(
        prog, __doc__, HERE / "esl_vs_lw.toml", "results/esl_vs_lw", overwrite=False
    )
    args = parser.parse_args(argv)
    if MPI.COMM_WORLD.size > 1:
        raise SystemExit("demos/esl_vs_lw.py runs on one rank (its static solver is serial)")
    summary = run(load_settings(args.config), Path(args.out))
    if "explicit_check" in summary:
        c = summary["explicit_check"]
        print(
            f"explicit check ({c['layup']}, refined): tip {c['tip_deflection_mm']:.6f} mm after "
            f"{c['steps']} steps vs static {c['static_tip_deflection_mm']:.6f} mm "
            f"({100 * c['relative_difference']:+.4f} %), "
            f"residual {c['final_relative_residual']:.1e}"
        )
    print(f"results in {args.out} ({summary['wall_time_s']:.0f} s)")


if __name__ == "__main__":
    script_main(main, PROG)
