"""The energy balance built from the states (kinetic + strain + stored cohesive + the damage laws'
own dissipation + damping) against the one built from the work of the internal forces, and the
dissipation accumulators of the damage laws.

Units: N, mm, s, tonne (energies in mJ).
"""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import toml_text
from mpi4py import MPI

from fenics_adaptive.io import checkpoint
from fenics_adaptive.io.output import read_history
from fenics_adaptive.materials.cohesive import (
    H_DISSIPATED,
    HISTORY,
    cohesive_element_force_tracked,
)
from fenics_adaptive.materials.laminate import PlyMaterial
from fenics_adaptive.materials.ply_damage import (
    RESIDUAL,
    S_D,
    S_DISSIPATED,
    material_point_update,
    new_state,
)
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import load_config
from fenics_adaptive.settings.materials import CohesiveLaw, PlyFailure

DATA = Path(__file__).parent / "data"

LAW = CohesiveLaw(K_n=1e5, K_s=1e5, N=20.0, S=40.0, GIc=0.4, GIIc=1.0, law="bk", exponent=2.0)


def unit_element(size: float = 1.0) -> np.ndarray:
    """Reference coordinates (8, 3) of a flat square cohesive element of side ``size`` (mm)."""
    corners = np.array([[a & 1, (a >> 1) & 1, 0.0] for a in range(4)], dtype=float) * size
    return np.vstack([corners, corners])


@pytest.mark.parametrize("steps", [999, 4000])
def test_cohesive_dissipation_to_separation_is_GIc_times_area(steps):
    """Opening one element in pure mode I to twice the final opening: the law's summed
    dissipation is GIc x area to 1e-3 (999 steps: the onset and final openings fall between
    steps), and it equals, at every step, the trapezoidal work of the element's forces minus
    its stored energy (to round-off: the consistent increment is exact for the secant law)."""
    size = 0.5
    X = unit_element(size)
    params = LAW.as_array()
    damage = np.zeros(4)
    history = np.zeros((4, HISTORY))
    f = np.zeros((8, 3))
    u = np.zeros((8, 3))
    final_opening = 2.0 * LAW.GIc / LAW.N
    work, f_old, u_old = 0.0, np.zeros((8, 3)), u.copy()
    worst = 0.0
    for opening in np.linspace(0.0, 2.0 * final_opening, steps + 1)[1:]:
        u[4:, 2] = opening
        stored, area = cohesive_element_force_tracked(X, u, params, damage, history, f)
        # f is the force the tractions apply to the nodes: the internal force is -f
        work += 0.5 * np.sum((-f_old - f) * (u - u_old))
        f_old, u_old = f.copy(), u.copy()
        dissipated = history[:, H_DISSIPATED].sum()
        worst = max(worst, abs(work - stored - dissipated))
    assert np.all(damage == 1.0)
    assert area == pytest.approx(size * size)
    assert dissipated == pytest.approx(LAW.GIc * size * size, rel=1e-3)
    assert worst < 1e-12 * LAW.GIc * size * size


def test_cohesive_dissipation_in_mixed_mode_matches_the_work():
    """Along a non-proportional mixed-mode path (shear, then opening) the consistent increment
    still equals the work not stored, to the second order of the step."""
    X = unit_element()
    params = LAW.as_array()
    damage, history = np.zeros(4), np.zeros((4, HISTORY))
    f, u = np.zeros((8, 3)), np.zeros((8, 3))
    work, f_old, u_old = 0.0, np.zeros((8, 3)), u.copy()
    n = 4000
    for s in np.linspace(0.0, 1.0, n + 1)[1:]:
        u[4:, 0] = 0.03 * min(2 * s, 1.0)
        u[4:, 2] = 0.05 * max(2 * s - 1.0, 0.0)
        stored, _ = cohesive_element_force_tracked(X, u, params, damage, history, f)
        work += 0.5 * np.sum((-f_old - f) * (u - u_old))
        f_old, u_old = f.copy(), u.copy()
    assert damage.min() == 1.0
    dissipated = history[:, H_DISSIPATED].sum()
    assert dissipated == pytest.approx(work - stored, rel=2e-3)


@pytest.mark.slow
def test_ply_dissipation_in_uniaxial_transverse_tension_is_G2c_over_band():
    """One ply point pulled across its fibres to full cracking: the law's summed dissipation
    density is G2c / l_c (the crack band's energy per unit volume) to 1e-3."""
    material = PlyMaterial(
        "m", E1=1.5e5, E2=9000.0, G12=5000.0, G23=3000.0, nu12=0.3, nu23=0.5, rho=1.6e-9
    )
    failure = PlyFailure("m", XT=2000.0, XC=1200.0, YT=60.0, YC=200.0, S12=90.0, G2c=0.28, G6c=0.79)
    band = 0.5
    state = new_state(1)[0]
    C0 = material.stiffness()
    # uniaxial strain across the fibres (eps_22 only): y = C22 eps^2 / 2
    eps_final = 2.0 * failure.G2c / (failure.YT * band) * C0[1, 1] / C0[1, 1]
    for eps in np.linspace(0.0, 3.0 * eps_final, 20001)[1:]:
        material_point_update(material, failure, np.array([0.0, eps, 0, 0, 0, 0]), band, state)
    assert state[S_D] == 1.0
    assert state[S_DISSIPATED] == pytest.approx(failure.G2c / band, rel=1e-3)
    assert RESIDUAL > 0.0


# ------------------------------------------------------------------ whole runs
def run_case(tmp_path: Path, data: dict, name: str) -> tuple[dict, dict]:
    path = tmp_path / f"{name}.toml"
    path.write_text(toml_text(data))
    config = load_config(path)
    summary, _structure = execute(config, tmp_path / name, MPI.COMM_WORLD, False, None)
    return read_history(tmp_path / name / "history.csv"), summary


def largest_energy(h: dict) -> float:
    return max(
        max(abs(x) for x in h[name])
        for name in ("external_work", "impact_work", "kinetic_energy", "internal_energy")
    )


def tcb(damping: float = 0.0) -> dict:
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["solver"]["end_time"] = 1.2e-4
    data["solver"]["mass_damping"] = damping
    data["output"].pop("fields_interval", None)
    return data


@pytest.mark.slow
@pytest.mark.parametrize("damping", [0.0, 5.0e5])
def test_balances_agree_on_a_mode_I_delamination(tmp_path, damping):
    """The short TCB delaminates (cohesive dissipation a large part of the work); the balance
    from the states equals the one from the work to 1e-5 of the largest energy (measured:
    1.6e-9 undamped), undamped and with mass damping."""
    h, summary = run_case(tmp_path, tcb(damping), "tcb")
    assert summary["status"] == "completed"
    largest = largest_energy(h)
    dissipated = h["cohesive_dissipation"][-1]
    assert dissipated > 0.2 * h["external_work"][-1]
    assert h["ply_dissipation"][-1] == 0.0
    if damping:
        assert h["damping_energy"][-1] > 0.01 * h["external_work"][-1]
    difference = np.abs(np.subtract(h["state_energy_balance"], h["energy_balance"]))
    assert difference.max() < 1e-5 * largest
    # and the dissipation the work implies is the law's
    implied = np.subtract(h["dissipated_energy"], h["cohesive_dissipation"])
    assert np.abs(implied).max() < 1e-5 * largest


def cross_ply_pull() -> dict:
    """A [0/90]s beam pulled along its length to 1.5 % strain: the 90-degree plies crack."""
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["model"]["ply_damage"] = True
    data["mesh"].update(length=10.0, width=1.0, nx=20, ny=2)
    data["materials"]["prototype"]["failure"] = {
        "XT": 2000.0,
        "XC": 1200.0,
        "YT": 60.0,
        "YC": 200.0,
        "S12": 90.0,
        "G2c": 0.28,
        "G6c": 0.79,
    }
    data["laminate"]["angles"] = [0, 90, 90, 0]
    data["prescribed"] = [
        {
            "face": "x1",
            "component": "x",
            "displacement": 0.15,
            "rise_time": 1.0e-4,
            "profile": "smooth",
        }
    ]
    data["solver"]["end_time"] = 1.2e-4
    data["output"].update(displacement_face="x1", reaction_face="x1", component="x")
    data["output"].pop("fields_interval", None)
    return data


@pytest.mark.slow
def test_balances_agree_with_ply_damage(tmp_path):
    """Matrix cracking of the 90-degree plies: the law's summed ply dissipation accounts for
    the work the materials did not store, and the two balances agree to 1e-4 of the largest
    energy (measured 1.3e-6; the law takes the energy release rate the ply's points release,
    so a strain gradient within a damaging ply no longer opens a gap)."""
    h, summary = run_case(tmp_path, cross_ply_pull(), "pull")
    assert summary["status"] == "completed"
    largest = largest_energy(h)
    assert h["ply_dissipation"][-1] > 0.01 * h["external_work"][-1]
    difference = np.abs(np.subtract(h["state_energy_balance"], h["energy_balance"]))
    assert difference.max() < 1e-4 * largest


@pytest.mark.slow
def test_dissipation_survives_a_restart(tmp_path):
    """Stopped half way and restarted, the run's dissipation columns equal the uninterrupted
    run's (the accumulators are in the checkpoint)."""
    data = tcb()
    data["output"]["checkpoint_interval"] = 1500
    full, _ = run_case(tmp_path, data, "full")
    path = tmp_path / "full.toml"
    config = load_config(path)
    folder = tmp_path / "full"
    manifest, arrays, _ = checkpoint.read(folder, MPI.COMM_WORLD, config)
    assert manifest["time_s"] > 0.0 and "structure_cohesive_history" in arrays
    # restart from the last checkpoint with a later end time: the extension's dissipation
    # continues from the stored one
    data["solver"]["end_time"] = 1.4e-4
    path.write_text(toml_text(data))
    config = load_config(path)
    execute(config, folder, MPI.COMM_WORLD, False, None, restart=folder)
    longer = read_history(folder / "history.csv")
    n = len(full["time"])
    assert longer["cohesive_dissipation"][:n] == pytest.approx(full["cohesive_dissipation"])
    assert longer["cohesive_dissipation"][-1] >= full["cohesive_dissipation"][-1]
    difference = np.abs(np.subtract(longer["state_energy_balance"], longer["energy_balance"]))
    assert difference.max() < 1e-3 * largest_energy(longer)
