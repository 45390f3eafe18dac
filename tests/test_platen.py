"""A rigid plane (``[[rigid]] shape = "plane"``) on every node (``face = "all"``): the platen
of a crush test.

- the penalty kernel against the closed form: force k <-g> n along the plane's normal, the
  energy 1/2 k g^2, the body's reaction the opposite;
- a [0/90]s tube pushed along its axis by a plane at its free end (static): the plane's force
  is the clamped end's reaction and E_x A / L times the end's shortening;
- explicit: the adaptive tube refined strongly from the start (the plane touches the extra
  nodes of its end) equals the layerwise tube of two sublaminates;
- the config refuses planes it cannot build, naming the key.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from helpers import (
    PROTOTYPE_PLY,
    assert_restarted_history,
    im7_tube,
    run_quietly,
    tube_config,
    with_cohesive_interface,
)

from fenics_adaptive.errors import InputError
from fenics_adaptive.io.output import read_history
from fenics_adaptive.model.contact import PLANE_AXIS, add_penalty_forces
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.static_runner import static_config

DATA = Path(__file__).parent / "data"
LENGTH = 30.0  # mm, the tube's
GAP = 1.0e-3  # mm between the plane and the tube's end at t = 0


def test_the_plane_pushes_along_its_normal_and_stores_its_energy():
    X = np.array([[10.2, 0.0, 0.0], [9.0, 3.0, 1.0], [10.0, -1.0, 0.5]])
    u = np.zeros(9)
    nodes = np.arange(3)
    normal = np.array([-1.0, 0.0, 0.0])  # the structure lies at x < 10
    centre = np.array([10.0, 7.0, -2.0])  # any point of the plane
    f, on_body = np.zeros(9), np.zeros(3)
    active = np.ones(3, dtype=bool)
    weights = np.array([2.0, 1.0, 0.5])  # each node's share: its spring is 50 N/mm x this
    energy = add_penalty_forces(
        u, nodes, active, X, centre, 0.0, PLANE_AXIS, normal, 50.0, weights, f, on_body
    )
    f = f.reshape(3, 3)
    np.testing.assert_allclose(f[0], [-100.0 * 0.2, 0.0, 0.0], rtol=1e-14)
    assert np.all(f[1:] == 0.0)  # inside the half space, and on the plane
    np.testing.assert_allclose(on_body, -f.sum(axis=0), rtol=1e-14)
    assert energy == pytest.approx(0.5 * 100.0 * 0.2**2, rel=1e-14)
    # a displacement that carries the first node back out of the plane frees it
    u[0] = -0.25
    f2 = np.zeros(9)
    energy = add_penalty_forces(
        u, nodes, active, X, centre, 0.0, PLANE_AXIS, normal, 50.0, weights, f2, on_body
    )
    assert energy == 0.0
    assert np.all(f2 == 0.0)


def _tube(kind: str) -> dict:
    """``helpers.tube_config`` pushed by a plane on every node at its x1 end instead."""
    data = tube_config(kind)
    data.pop("prescribed")
    data["rigid"] = [
        {
            "name": "platen",
            "shape": "plane",
            "normal": [-2.0, 0.0, 0.0],  # (scaled to 1)
            "position": [LENGTH + GAP, 0.0, 0.0],
            "face": "all",
            "motion": "prescribed",
            "displacement": [-0.021, 0.0, 0.0],
            "rise_time": 5.0e-5,
            "penalty": 2.0e4,
        }
    ]
    return data


def test_a_plane_crushing_a_tube_carries_its_membrane_stiffness(tmp_path):
    """Static: the plane's force (the tube pushing it back, along minus its normal) equals the
    clamped end's reaction, and the membrane stiffness E_x A / L of the faceted wall (as
    ``test_shell.test_tube_compression_carries_the_membrane_stiffness``, +0.16 % of the ends'
    Poisson restraint) times the end's shortening; the plane moved its 0.021 mm."""
    data = _tube("esl")
    summary = static_config(parse_config(data), tmp_path / "static", log=None)
    force = np.array(summary["rigid_bodies"]["platen"]["force_N"])
    reaction = summary["final"]["reaction_force_N"]
    shortening = -summary["final"]["displacement_mm"]
    assert force[0] > 100.0 and abs(force[1]) < 1e-9 * force[0] and abs(force[2]) < 1e-9 * force[0]
    assert reaction == pytest.approx(force[0], rel=1e-6)  # the clamp pushes along +x too
    history = read_history(tmp_path / "static" / "history.csv")  # along minus the normal
    assert history["platen_force"][-1] == pytest.approx(force[0], rel=1e-12)
    assert history["platen_displacement"][-1] == pytest.approx(-0.021, rel=1e-12)
    ply = PROTOTYPE_PLY
    nu21 = ply["nu12"] * ply["E2"] / ply["E1"]
    Q11, Q22 = ply["E1"] / (1 - ply["nu12"] * nu21), ply["E2"] / (1 - ply["nu12"] * nu21)
    Q12 = ply["nu12"] * Q22
    A11 = 0.5 * (Q11 + Q22)
    section = 12 * 2 * 20.0 * np.sin(np.pi / 12) * 1.0
    stiffness = (A11 - Q12**2 / A11) * section / LENGTH
    assert force[0] == pytest.approx(stiffness * shortening * 1.0016, rel=0.003)
    # the penetration the penalty needs: the force over the end's springs, 24 nodes of half a
    # face node's mass each (two cells around a node at the end, not four)
    assert 0.021 - GAP - shortening == pytest.approx(force[0] / (12 * 2.0e4), rel=0.01)


def test_a_plane_on_a_tube_refined_from_the_start_is_the_plane_on_the_layerwise_tube(tmp_path):
    """Explicit: the plane presses the tube's end, the adaptive tube's extra nodes there
    included; refined strongly from t = 0 it gives the layerwise tube's history to round-off
    (force on the plane, reaction, energies), and the plane's force is the reaction once the
    tube's waves have settled into the quasi-static share."""
    adaptive = with_cohesive_interface(_tube("adaptive"), "strong")
    layerwise = with_cohesive_interface(_tube("layerwise"), None)
    layerwise["mesh"]["layers"] = [2, 2]
    run_quietly(adaptive, tmp_path / "adaptive")
    run_quietly(layerwise, tmp_path / "layerwise")
    rows = [
        {k: np.asarray(v) for k, v in read_history(tmp_path / f / "history.csv").items()}
        for f in ("adaptive", "layerwise")
    ]
    force = rows[1]["platen_force"]
    assert force.max() > 100.0  # the plane carries load
    for column in ("platen_force", "reaction_force", "internal_energy", "impact_work"):
        scale = np.abs(rows[1][column]).max()
        np.testing.assert_allclose(rows[0][column], rows[1][column], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(rows[1]["platen_displacement"][-1], -0.021, rtol=1e-12)


@pytest.mark.parametrize(
    ("change", "key", "words"),
    [
        (lambda b: b.pop("normal"), "rigid[0].normal", "needs its normal"),
        (lambda b: b.update(radius=2.0), "rigid[0].radius", "does not apply"),
        (lambda b: b.update(normal=[0.0, 0.0, 0.0]), "rigid[0].normal", "zero vector"),
        (lambda b: b.update(axis="x"), "rigid[0].axis", "has no axis"),
        (lambda b: b.update(friction=0.2), "rigid[0].friction", "not supported yet"),
        (lambda b: b.update(shape="sphere"), "rigid[0].radius", "needs its radius"),
    ],
)
def test_the_config_refuses_a_plane_it_cannot_build(change, key, words):
    data = copy.deepcopy(_tube("esl"))
    change(data["rigid"][0])
    with pytest.raises(InputError, match=words) as error:
        parse_config(data)
    assert error.value.key == key


def test_a_plane_that_starts_inside_the_structure_is_refused(tmp_path):
    data = _tube("esl")
    data["rigid"][0]["position"] = [LENGTH - 0.5, 0.0, 0.0]
    with pytest.raises(InputError, match="inside the structure"):
        run_quietly(data, tmp_path / "inside")


def test_the_impactor_is_no_plane():
    data = _tube("esl")
    data.pop("rigid")
    data["impactor"] = {"shape": "plane", "radius": 1.0, "mass": 1e-6,
                        "position": [0, 0, 30], "velocity": [0, 0, -1]}  # fmt: skip
    with pytest.raises(InputError) as error:
        parse_config(data)
    assert error.value.key == "impactor.shape"


def test_refinement_under_a_plane_books_the_springs_it_moves_and_restarts(tmp_path):
    """Refining a column under the plate moves its springs to the new nodes (tens of mJ here:
    the plate's rim contact is concentrated): booked as refinement energy, the energy balance
    stays closed (it was -20 mJ without); a run stopped half-way and restarted from its
    checkpoint gives the uninterrupted history (the springs found again, the booked energy
    kept)."""
    whole = im7_tube()
    first = copy.deepcopy(whole)
    first["solver"]["end_time"] = 5.0e-5
    first["output"]["checkpoint_interval"] = 300
    run_quietly(whole, tmp_path / "whole")
    run_quietly(first, tmp_path / "split")
    run_quietly(whole, tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", tmp_path / "whole", atol=1e-9)
    rows = {k: np.asarray(v) for k, v in read_history(tmp_path / "whole" / "history.csv").items()}
    assert rows["refinement_energy"].min() < -5.0  # springs moved, booked
    assert np.abs(rows["energy_balance"]).max() < 1e-3 * rows["impact_work"].max()


def test_a_plane_lets_go_of_the_extra_nodes_erosion_has_freed():
    """tests/data/perforation.toml refined strongly at its middle interface from the start,
    under a plane on every node: with the four cells around the plate's centre eroded, the
    extra nodes of their shared column leave the contact (no element holds them), the other
    extra nodes stay, and a refinement's new extra nodes do not bring the freed ones back."""
    import tomllib

    from fenics_adaptive.materials import ply_damage as pd
    from fenics_adaptive.model.contact import Contact
    from fenics_adaptive.simulation import build_structure

    data = tomllib.loads((DATA / "perforation.toml").read_text())
    data["model"]["kind"] = "adaptive"
    data["interfaces"] = {"delaminate": [2], "initial": "strong"}
    data["cohesive"] = {"K_n": 1.0e5, "K_s": 1.0e5, "N": 60.0, "S": 90.0, "GIc": 0.28,
                        "GIIc": 0.79, "law": "bk", "exponent": 2.1}  # fmt: skip
    data.pop("impactor")
    data["rigid"] = [{"name": "platen", "shape": "plane", "normal": [0.0, 0.0, -1.0],
                      "position": [5.0, 5.0, 1.01], "face": "all", "motion": "fixed"}]  # fmt: skip
    config = parse_config(data)
    structure = build_structure(config)
    contact = Contact.on(config.rigid_bodies[0], structure)
    contact.watch_erosion(structure)  # (as Contact.on does on an eroding structure)
    f_base = np.zeros(structure.base.u.x.array.shape)
    f_extra = np.zeros(structure.extra.vectors["u"].array.shape)
    contact.add_force(0.0, f_base, f_extra)  # (finds the extra nodes)
    X = contact.extra_X
    centre = np.flatnonzero(np.all(np.isclose(X[:, :2], [5.0, 5.0]), axis=1))
    cells = np.flatnonzero(
        np.all(np.abs(structure.cell_vertices().mean(axis=1)[:, :2] - 5.0) < 0.5, axis=1)
    )
    assert len(centre) == 2 and len(cells) == 4  # the pair of the split interface
    structure.damage_state[cells, :, pd.S_DF] = 1.0
    contact.release()
    assert np.flatnonzero(~contact.extra_active).tolist() == centre.tolist()
    contact.generation = -2  # as after a refinement: the extra nodes found again
    contact.add_force(0.0, f_base, f_extra)
    assert np.flatnonzero(~contact.extra_active).tolist() == centre.tolist()
