"""The mixed-mode bending test (MMB, ASTM D6671): its beam theory, the lever of the config, and a
short MMB loaded through the lever.

- theory: G = P^2 / (2 b) dC/da of the compliance (Irwin-Kies, a numerical derivative) equals
  the energy release rates of ``mmb_energy_release``; ``mmb_load_arm`` gives the mixity it is
  asked for; c = L / 3 is the ENF; a history made from the theory is judged exact;
- config: a lever that names no saddle, a saddle the lever does not carry, a load point with
  two motions, a body named like the lever's columns, and a static solve of a lever: refused;
- a short MMB (L = 25 mm) loaded through the lever: the massless lever's equilibrium (hinge
  and load shares of the saddle's force) and kinematics (the saddle's height), the work P dw_P
  of its load point against the work given to the structure, the energy balance, and the
  elastic slope of beam theory; stopped half-way and restarted, it goes on as if never stopped;
  the adaptive model refined from the start gives the layerwise model's history.
"""

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import (
    assert_on_the_propagation_branch,
    assert_restarted_history,
    quick_fracture_run,
    run_quietly,
    theory_history,
)

from fenics_adaptive.analysis.lefm import (
    enf_compliance,
    mmb_comparison,
    mmb_compliance,
    mmb_energy_release,
    mmb_force,
    mmb_load_arm,
    mmb_propagation_force,
    root_rotation_correction,
)
from fenics_adaptive.analysis.studies import fracture_variant, mmb_mixity, mmb_quick
from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.materials.cohesive import critical_energy
from fenics_adaptive.runner import run_config
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.static_runner import linearised

DEMOS = Path(__file__).parent.parent / "demos"
E1, G12, WIDTH, ARM = 120e3, 5e3, 25.0, 1.5  # MPa, MPa, mm, mm


@pytest.fixture(scope="module")
def base() -> dict:
    return tomllib.loads((DEMOS / "fracture_tests_mmb.toml").read_text())


@pytest.mark.parametrize("chi", [0.0, 1.7])
@pytest.mark.parametrize("load_arm", [30.0, 60.0, 150.0])
def test_the_energy_release_rates_are_the_compliance_s_derivative(load_arm, chi):
    L = 50.0
    for a in (20.0, 35.0, 45.0):
        step = 1e-4 * a
        beam = (load_arm, L, E1, G12, WIDTH, ARM, chi)
        slope = (mmb_compliance(a + step, *beam) - mmb_compliance(a - step, *beam)) / (2 * step)
        g_I, g_II = mmb_energy_release(a, load_arm, L, E1, WIDTH, ARM, chi)
        assert slope / (2 * WIDTH) == pytest.approx(g_I + g_II, rel=1e-7)


@pytest.mark.parametrize("mixity", [0.1, 0.2, 0.5, 0.8, 0.95])
def test_the_load_arm_gives_the_mixity_asked_for(mixity):
    L = 51.0
    c = mmb_load_arm(mixity, L)
    assert c > L / 3  # the arms are pulled open
    for a in (10.0, 30.0):
        g_I, g_II = mmb_energy_release(a, c, L, E1, WIDTH, ARM, 0.0)
        assert g_II / (g_I + g_II) == pytest.approx(mixity, rel=1e-12)
    with pytest.raises(ValueError, match="mixity"):
        mmb_load_arm(1.0, L)


def test_a_lever_with_c_of_a_third_of_L_is_the_enf():
    """P_I = 0 at c = L/3: no mode I, and the load point moves (P_II / P) = 4/3 times the
    mid-span of an ENF loaded by 4/3 P."""
    L, a = 50.0, 30.0
    g_I, _ = mmb_energy_release(a, L / 3, L, E1, WIDTH, ARM, 1.7)
    assert g_I == pytest.approx(0.0, abs=1e-30)
    assert mmb_compliance(a, L / 3, L, E1, G12, WIDTH, ARM, 1.7) == pytest.approx(
        (4 / 3) ** 2 * enf_compliance(a, L, E1, G12, WIDTH, ARM), rel=1e-12
    )


def test_mmb_comparison_of_a_history_that_follows_the_theory_finds_it_exact(base):
    config = parse_config(base)
    material, law = config.laminate.plies[0].material, config.cohesive
    b, h, c = config.mesh.width, 1.56, config.lever.load_arm
    L, a0 = 80.0, 60.0
    chi = root_rotation_correction(material)
    beam = (material.E1, material.G12, b, h, chi)
    cracks = np.linspace(a0, L - 0.5, 200)
    force = mmb_propagation_force(cracks, c, L, material.E1, b, h, chi, law)
    compliance = mmb_compliance(cracks, c, L, *beam)
    g_I, g_II = mmb_energy_release(a0, c, L, material.E1, b, h, chi)
    Gc = critical_energy(law, float(g_II / (g_I + g_II)))
    history = theory_history("lever", a0, cracks, force, compliance, b, Gc)
    comparison = mmb_comparison(config, history)
    assert comparison["a0_mm"] == a0 and comparison["half_span_mm"] == L
    assert comparison["mixity"] == pytest.approx(0.5, abs=0.05)
    assert comparison["Gc_N_per_mm"] == pytest.approx(Gc, rel=1e-12)
    assert comparison["stable_growth"]
    assert comparison["peak_over_initiation"] == pytest.approx(1.0, rel=1e-12)
    assert comparison["initial_stiffness_N_per_mm"] == pytest.approx(
        comparison["theory_stiffness_N_per_mm"], rel=1e-9
    )
    assert comparison["force_over_theory_min"] == pytest.approx(1.0, rel=1e-4)
    assert comparison["force_over_theory_max"] == pytest.approx(1.0, rel=1e-4)
    assert comparison["dissipation_rate_over_Gc"] == pytest.approx(1.0, rel=1e-9)
    theory = mmb_force(-history["lever_displacement"], c, L, a0, *beam, law)
    assert np.allclose(theory, history["lever_force"], rtol=1e-4)


def test_mmb_mixity_sets_the_load_arm_and_keeps_the_run_as_quasi_static(base):
    data = mmb_mixity(base, 0.2)
    assert data["lever"]["load_arm"] == pytest.approx(mmb_load_arm(0.2, 80.0), abs=1e-3)
    assert abs(data["lever"]["velocity"]) > abs(base["lever"]["velocity"])  # longer travel
    assert base["lever"]["load_arm"] == 70.0  # the base is not changed


def refusal(data: dict) -> InputError:
    with pytest.raises(InputError) as caught:
        parse_config(data)
    return caught.value


def test_a_lever_config_that_cannot_work_is_refused(base):
    data = copy.deepcopy(base)
    del data["lever"]
    assert "rigid.saddle.motion" in str(refusal(data))
    data = copy.deepcopy(base)
    data["lever"]["saddle"] = "nose"
    assert "'nose' is no [[rigid]] body (known: roller, saddle)" in str(refusal(data))
    data = copy.deepcopy(base)
    data["lever"]["saddle"] = "roller"
    assert 'give it motion = "lever"' in str(refusal(data))
    data = copy.deepcopy(base)
    data["lever"]["displacement"] = -5.0
    assert "velocity or a displacement" in str(refusal(data))
    data = copy.deepcopy(base)
    data["rigid"][0]["name"] = "hinge"
    assert "history columns are taken" in str(refusal(data))
    data = copy.deepcopy(base)
    data["lever"]["hinge"] = "x2&top"
    assert "unknown face 'x2'" in str(refusal(data))
    with pytest.raises(InputError, match="static solve has no lever"):
        linearised(parse_config(base))


def short_mmb(base: dict) -> dict:
    """The demo's MMB made short (L = 25 mm, a0 = 17 mm), loaded elastically to about 0.7 of
    the initiation load in 2.5 ms (its first bending period is about 0.2 ms)."""
    data = copy.deepcopy(base)
    half_span, overhang, a0 = 25.0, 5.0, 17.0
    length = overhang + 2 * half_span
    data["mesh"].update(length=length, nx=round(length))
    data["delamination"][0].update(x_min=length - a0, x_max=length)
    data["rigid"][1]["position"][0] = overhang + half_span
    data["lever"].update(load_arm=round(mmb_load_arm(0.5, half_span), 3), velocity=-400.0,
                         rise_time=5e-4)  # fmt: skip
    data["solver"]["end_time"] = 2.5e-3
    data["output"]["interval"] = 2.5e-5
    data["cohesive"].update(N=80.0, S=100.0)  # the material's: no damage onset on the way
    return data


@pytest.mark.slow
def test_a_short_mmb_loaded_through_the_lever(base, tmp_path):
    data = short_mmb(base)
    config = parse_config(data)
    run_config(config, tmp_path / "whole")
    h = {k: np.asarray(v) for k, v in read_history(tmp_path / "whole" / "history.csv").items()}
    # stopped half-way and restarted: the lever's state (its hinge's last force and
    # displacement, their work, the saddle's) carries the run on as if never stopped
    first = copy.deepcopy(data)
    first["solver"]["end_time"] = 0.5 * data["solver"]["end_time"]
    first["output"]["checkpoint_interval"] = 5000
    run_quietly(first, tmp_path / "split")
    run_quietly(data, tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole", atol=1e-12)
    L, c = 25.0, config.lever.load_arm
    # the massless lever's equilibrium, each row
    assert np.allclose(h["lever_force"], h["saddle_force"] * L / (L + c), rtol=1e-12, atol=0)
    assert np.allclose(h["hinge_force"], h["saddle_force"] * c / (L + c), rtol=1e-12, atol=0)
    # the saddle sits where the rigid lever puts it
    assert np.allclose(
        h["saddle_displacement"],
        (L * h["lever_displacement"] + c * h["hinge_displacement"]) / (L + c),
        rtol=1e-12, atol=1e-15,
    )  # fmt: skip
    # the load point's work (trapezoidal over the rows) is what the lever and the roller gave
    # the structure plus what their penalty springs hold (under 1 %)
    P, w = h["lever_force"], -h["lever_displacement"]
    work = float(np.sum(0.5 * (P[1:] + P[:-1]) * np.diff(w)))
    assert 0.0 < work - h["impact_work"][-1] < 0.01 * work
    assert np.abs(h["energy_balance"]).max() < 1e-6 * h["impact_work"][-1]
    # elastic: no growth, and the slope of beam theory
    comparison = mmb_comparison(config, h)
    assert h["crack_growth_area"].max() == 0.0
    assert comparison["peak_force_N"] < 0.9 * comparison["initiation_force_N"]
    assert comparison["initial_stiffness_N_per_mm"] == pytest.approx(
        comparison["theory_stiffness_N_per_mm"], rel=0.03
    )
    assert comparison["kinetic_energy_share"] < 0.05


@pytest.mark.slow
def test_the_adaptive_mmb_refined_from_the_start_is_the_layerwise_one(base, tmp_path):
    """Through the lever too: the adaptive element refined strongly at the film's interface
    from the start gives the layerwise model's history (the first millisecond, in contact)."""
    histories = {}
    for name in ("layerwise", "refined_from_start"):
        data = fracture_variant(short_mmb(base), name)
        data["solver"]["end_time"] = 1.0e-3
        run_config(parse_config(data), tmp_path / name)
        histories[name] = read_history(tmp_path / name / "history.csv")
    layerwise, adaptive = histories["layerwise"], histories["refined_from_start"]
    assert max(layerwise["lever_force"]) > 50.0
    for column in ("lever_force", "hinge_force", "hinge_displacement", "saddle_displacement",
                   "roller_force", "internal_energy"):  # fmt: skip
        scale = np.abs(layerwise[column]).max()
        np.testing.assert_allclose(adaptive[column], layerwise[column], rtol=0, atol=1e-9 * scale,
                                   err_msg=column)  # fmt: skip


@pytest.mark.slow
def test_a_quick_mmb_grows_its_crack_on_the_propagation_branch(base, tmp_path):
    """The MMB of demos/fracture_tests_mmb.toml made short (``mmb_quick``: 0.78 mm arms, L =
    36 mm, a0 = 27 mm, c = 31.5 mm for G_II / G = 0.48, the lever's load point fast to near
    initiation, slow after; about 60 s): the crack grows stably on corrected beam theory's
    mixed-mode branch (mean within 3 %, each bin within 5 %), the peak within 5 % of the
    initiation load, the elastic slope within 5 %, the kinetic energy under 1 % of the work
    while the crack grows. Each grown element dissipates the BK law's Gc at the theory's
    mixity times its area within 6 %: measured 0.99 - 1.06 (the sum +3.7 %). The mixity along
    a process zone's opening path is not the beam theory's global one (mode I opens first at
    the front); the demo's 1 mm MMB shows the same at G_II / G = 0.2 (+2.5 %)."""
    config, history, dissipated, areas = quick_fracture_run(mmb_quick(base), tmp_path)
    c = mmb_comparison(config, history)
    assert_on_the_propagation_branch(c, history)
    assert c["crack_length_range_mm"][1] >= c["half_span_mm"] - 2.0
    assert c["initial_stiffness_N_per_mm"] == pytest.approx(c["theory_stiffness_N_per_mm"], 0.05)
    assert len(areas) >= 6
    assert np.allclose(dissipated / (areas * c["Gc_N_per_mm"]), 1.0, atol=0.06)
