"""Refinement indicators: recovered out-of-plane stresses, the interface initiation indicator,
manual triggers and spreading."""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenics_adaptive import enrichment as enr
from fenics_adaptive import explicit, loading
from fenics_adaptive import indicators as ind
from fenics_adaptive.config import parse_config
from fenics_adaptive.laminate import Laminate, PlyMaterial
from fenics_adaptive.model import build_model
from fenics_adaptive.runner import build_structure, probe_displacement, refinement_hook
from fenics_adaptive.static import solve_static
from fenics_adaptive.structure import Structure
from meshes import esl_mesh

DATA = Path(__file__).parent / "data"
PLY = PlyMaterial("ply", E1=1e5, E2=1e4, G12=5e3, nu12=0.25, nu23=0.25, rho=1.6e-9)


def loaded_cantilever(angles, force=-1.0):
    """50 x 2 x 2 mm cantilever, tip load, static: the exact transverse shear is known."""
    laminate = Laminate.from_angles(PLY, angles, 0.25)
    beam = esl_mesh(MPI.COMM_WORLD, 50.0, 2.0, 50, 2, laminate.thickness)
    model = build_model(beam, [laminate])
    motions = loading.clamp("x0")
    load = loading.FaceLoad("x1", (0.0, 0.0, force), loading.Amplitude.constant())
    loads = loading.resolve(model, motions, [load])
    solve_static(model, motions, loads, 0.0)
    return Structure(model, loads), laminate


def beam_shear(laminate, shear_force, width):
    """Narrow-beam laminate theory: tau_xz(z) = -V / (b EI) * b * sum E_x,k int z dz, from the
    bottom face, z measured from the mid-plane."""
    EI = laminate.narrow_beam_bending_stiffness(width)
    z = laminate.ply_fractions * laminate.thickness - 0.5 * laminate.thickness
    E_x = [1.0 / np.linalg.inv(p.stiffness())[0, 0] for p in laminate.plies]
    first_moment = np.concatenate(
        [[0.0], np.cumsum([E * (z[k + 1] ** 2 - z[k] ** 2) / 2 for k, E in enumerate(E_x)])]
    )
    return -shear_force / EI * first_moment


@pytest.mark.parametrize("angles", [[0] * 8, [0, 90, 0, 90, 90, 0, 90, 0]])
def test_recovered_transverse_shear_matches_beam_theory(angles):
    structure, laminate = loaded_cantilever(angles)
    recovered = ind.recovered_interface_stresses(structure)
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    mid_span = (x > 15.0) & (x < 35.0)
    tau = recovered[mid_span, :, 1].mean(axis=0)
    expected = beam_shear(laminate, -1.0, 2.0)
    peak = np.abs(expected).max()
    assert peak == pytest.approx(3 / (2 * 4.0), rel=0.02) or angles != [0] * 8
    assert np.abs(tau - expected).max() < 0.03 * peak
    # the constitutive shear of the ESL element is nearly constant through the thickness:
    # what the recovery is for
    constitutive = ind.ply_stresses(structure)[mid_span, :, 4].mean(axis=0)
    assert np.ptp(constitutive) < 0.35 * peak
    # no peel stress in a tip-loaded cantilever away from its ends
    assert np.abs(recovered[mid_span, :, 0]).max() < 0.02 * peak


def test_interface_indicator_flags_the_most_stressed_interface():
    structure, _ = loaded_cantilever([0] * 8, force=-60.0)  # tau_max = 22.5 MPa
    recovered = ind.recovered_interface_stresses(structure)
    index = ind.interface_initiation(recovered, strength_n=20.0, strength_s=40.0)
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    inner = (x > 5.0) & (x < 45.0)
    # the mid-plane (interface 4) carries the peak shear: 22.5 / 40
    assert index[inner, 3].mean() == pytest.approx(22.5 / 40.0, rel=0.03)
    assert index[inner].argmax(axis=1).tolist() == [3] * inner.sum()


def tcb(**changes):
    data = tomllib.loads((DATA / "tcb_adaptive.toml").read_text())
    data["interfaces"]["initial"] = "none"
    data.update(changes)
    return data


def test_manual_refinement_by_displacement():
    data = tcb(refinement=[{"displacement": 0.0023, "interfaces": [2, 6], "kind": "strong"}])
    data["solver"]["end_time"] = 2.0e-5
    config = parse_config(data)
    structure = build_structure(config)
    hook = refinement_hook(config)
    at = []

    def on_step(t, s):
        displacement = probe_displacement(s, config.probe)
        changed = hook(t, s)
        if changed:
            at.append(displacement)
        return changed

    stats = explicit.run(structure, config.solver, config.probe, on_step=on_step)
    assert stats.refinements == 1
    assert (structure.interface_state[:, [1, 5]] == enr.STRONG).all()
    assert (structure.interface_state[:, 3] == enr.NONE).all()
    # on the first step past 0.0023 mm (the tip moves at most 1000 mm/s x 4e-8 s per step)
    assert 0.0023 <= at[0] < 0.0023 + 1000.0 * 4e-8


def test_spread_reaches_the_neighbours_once_per_ring():
    structure = build_structure(parse_config(tcb()))
    x = structure.X_base[structure.bottom_local][:, :, 0].mean(axis=1)
    middle = int(np.argmin(np.abs(x - 5.25)))
    one = ind.spread(structure, [(middle, 2, enr.STRONG)], 1)
    two = ind.spread(structure, [(middle, 2, enr.STRONG)], 2)
    cells = lambda requests: sorted(np.round(x[[c for c, _, _ in requests]], 6))  # noqa: E731
    assert cells(one) == [4.75, 5.25, 5.75]
    assert cells(two) == [4.25, 4.75, 5.25, 5.75, 6.25]
    assert {(i, k) for _, i, k in two} == {(2, enr.STRONG)}
