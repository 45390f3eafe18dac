"""Coulomb friction between a rigid body and the laminate (``model.contact.add_friction_forces``).

- one node pressed into a body and slid along it, against the law written out by hand: stick
  with the tangential spring, slip at mu f_n, the dissipation mu f_n times the slip beyond the
  spring's, unloading back through the spring, nothing held once the contact opens;
- a cylinder pressed into a block on the ground and dragged along it: the energy friction
  dissipated is mu times the normal force integrated over the slide, the run's energy balance
  closes with it booked, and a restart repeats the run.
Units: N, mm, s, tonne (mJ).
"""

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_restarted_history, run_quietly

from fenics_adaptive.io.output import read_history
from fenics_adaptive.model.contact import add_friction_forces, add_penalty_forces
from fenics_adaptive.settings.config import parse_config

DATA = Path(__file__).parent / "data"
PENALTY, MU, RADIUS = 200.0, 0.3, 10.0


def slide_one_node(path_x, depth: float):
    """A node under a cylinder along x of radius 10, its axis 10 - depth above the node (the
    normal along z, f_n = k depth whatever x), the body moved along its axis to ``path_x``
    (mm, one call each): per call the tangential force on the node (x), the normal force
    (pushing it down), the springs' energy and the dissipation."""
    X = np.zeros((1, 3))
    u = np.zeros(3)
    nodes = np.array([0])
    previous, traction = np.zeros((1, 3)), np.zeros((1, 3))
    centre = np.array([0.0, 0.0, RADIUS - depth])
    out, last = [], 0.0
    for x in path_x:
        centre[0] = x
        moved = np.array([x - last, 0.0, 0.0])
        last = x
        f, total = np.zeros(3), np.zeros(3)
        active = np.ones(len(nodes), dtype=bool)
        add_penalty_forces(
            u, nodes, active, X, centre, RADIUS, 0, np.zeros(3), PENALTY, np.ones(1), f, total
        )
        normal = -f[2]
        springs, dissipated = add_friction_forces(
            u, nodes, active, X, centre, moved, RADIUS, 0, np.zeros(3), PENALTY, MU, previous,
            traction, f, total,
        )  # fmt: skip
        np.testing.assert_allclose(total, -f, rtol=0, atol=1e-15)  # the body's reaction
        out.append((f[0], normal, springs, dissipated))
    return np.array(out)


def test_one_node_sticks_slips_at_mu_fn_and_dissipates_the_slip_beyond_the_spring():
    depth = 1e-3  # the normal force k depth = 0.2 N; the stick holds mu k depth / k = 3e-4 mm
    step = 1e-4
    forward = np.arange(1, 11) * step  # 1 mm of body travel: the node slides back by it
    back = forward[-1] - np.arange(1, 9) * step  # then the body returns 0.8 mm
    history = slide_one_node(np.concatenate([forward, back]), depth)
    tangential, normal, springs, dissipated = history.T
    limit = MU * PENALTY * depth
    # the normal force is the plain penalty's, unchanged by friction
    np.testing.assert_allclose(normal, PENALTY * depth, rtol=1e-9)
    # stick: the spring's force -k (slide), the node dragged along with the body (+x)
    np.testing.assert_allclose(tangential[:3], PENALTY * forward[:3], rtol=1e-9)
    assert dissipated[:3] == pytest.approx(0.0, abs=1e-15)
    # slip: mu f_n, each further step dissipating mu f_n times the slip beyond the spring's
    np.testing.assert_allclose(tangential[3:10], limit, rtol=1e-12)
    slipped = forward[9] - limit / PENALTY
    assert dissipated[:10].sum() == pytest.approx(limit * slipped, rel=1e-9)
    assert springs[9] == pytest.approx(0.5 * limit**2 / PENALTY, rel=1e-12)
    # the body turns back: the spring unloads through zero into the other direction (2 mu f_n
    # over 6 steps of k step = mu f_n / 3), then slips the other way
    np.testing.assert_allclose(
        tangential[10:15], limit - PENALTY * step * np.arange(1, 6), rtol=0, atol=1e-12 * limit
    )
    assert np.abs(dissipated[10:15]).max() < 1e-15
    np.testing.assert_allclose(tangential[16:], -limit, rtol=1e-9)
    assert dissipated[16:].min() > 0.9 * limit * step
    # out of contact the node holds nothing, and what its spring held is dissipated
    released = slide_one_node([0.0, 1e-4, 2e-4], depth=-1e-3)
    assert np.all(released[:, 0] == 0.0) and np.all(released[:, 2:] == 0.0)


def dragged_block(friction: float) -> dict:
    """A [0/90]2s block 20 x 2 x 2 mm on the ground (bottom clamped), a cylinder (axis y,
    R = 20 mm) starting 0.001 mm above its top, dragged 8 mm along it while pressing 0.04 mm
    down."""
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    data["mesh"].update(nx=40, ny=2)
    data["clamp"] = [{"face": "bottom"}]
    data.pop("prescribed")
    top = 8 * 0.25
    data["rigid"] = [
        {
            "name": "slider",
            "shape": "cylinder",
            "axis": "y",
            "radius": 20.0,
            "position": [6.0, 1.0, top + 20.0 + 0.001],
            "face": "top",
            "motion": "prescribed",
            "displacement": [8.0, 0.0, -0.04],
            "rise_time": 2.0e-4,
            "profile": "linear",
            "friction": friction,
        }
    ]
    data["solver"].update(end_time=2.0e-4, mass_damping=2.0e4)
    data["output"].update(interval=2.0e-6, displacement_face="top", reaction_face="bottom")
    data["output"].pop("fields_interval", None)
    return data


@pytest.fixture(scope="module")
def dragged(tmp_path_factory):
    out = tmp_path_factory.mktemp("dragged")
    run_quietly(dragged_block(MU), out / "run")
    return out, read_history(out / "run" / "history.csv")


def test_dragging_dissipates_mu_times_the_normal_force_over_the_slide(dragged):
    _, h = dragged
    x = 8.0 * np.array(h["time"]) / 2.0e-4  # the body's travel (mm)
    normal = np.array(h["slider_force"])  # z: the block pushes the body up
    friction = np.array(h["slider_friction_energy"])
    assert normal[-1] > 1.0 and friction[-1] > 1.0  # N, mJ
    # less by what the block's surface moved with the body (its shear) and the spring's slip
    assert friction[-1] == pytest.approx(MU * np.trapezoid(normal, x), rel=0.005)
    assert np.all(np.diff(friction) >= -1e-12 * friction[-1])
    # the balance closes with the dissipation booked (impact_work is the work on the block)
    balance = np.abs(np.array(h["energy_balance"])).max()
    assert balance < 1e-5 * friction[-1], balance


def test_a_frictionless_body_drags_nothing_and_a_restart_repeats_the_run(dragged, tmp_path):
    out, h = dragged
    run_quietly(dragged_block(0.0), tmp_path / "frictionless")
    plain = read_history(tmp_path / "frictionless" / "history.csv")
    assert "slider_friction_energy" not in plain
    # friction works against the drag: the drive puts in more than without it
    assert h["impact_work"][-1] + h["slider_friction_energy"][-1] > 1.5 * plain["impact_work"][-1]
    # the nodes' tangential forces and positions, the body's last centre and the dissipation
    # so far go into the checkpoint: the resumed run is the uninterrupted one
    first = dragged_block(MU)
    first["solver"]["end_time"] = 1.2e-4
    first["output"]["checkpoint_interval"] = 10_000
    run_quietly(first, tmp_path / "split")
    run_quietly(dragged_block(MU), tmp_path / "split", restart=tmp_path / "split")
    assert_restarted_history(tmp_path / "split", out / "run", atol=1e-12)


def test_the_config_takes_a_friction_coefficient_and_refuses_a_negative_one():
    config = parse_config(dragged_block(0.25))
    assert config.rigid_bodies[0].friction == 0.25
    bad = copy.deepcopy(dragged_block(0.25))
    bad["rigid"][0]["friction"] = -0.1
    with pytest.raises(Exception, match="friction"):
        parse_config(bad)


def test_a_free_impactor_that_rubs_the_plate_keeps_the_energy_balance(tmp_path):
    """An [impactor] (a free body, its force summed over the ranks every step) striking
    obliquely with friction: what friction dissipates is booked, and the balance moves by no
    more than the frictionless run's (the contact's own O(dt^2)); the impact work and the
    dissipation differ from the frictionless run's."""
    runs = {}
    for mu in (0.0, 0.3):
        data = tomllib.loads((DATA / "mpi_one_rank_impact.toml").read_text())
        data["impactor"].update(velocity=[3000.0, 0.0, -6000.0], friction=mu)
        data["output"].pop("fields_interval", None)
        run_quietly(data, tmp_path / str(mu))
        runs[mu] = read_history(tmp_path / str(mu) / "history.csv")
    kinetic = 0.5 * 2.0e-6 * (3000.0**2 + 6000.0**2)  # mJ, the impactor's at t = 0
    rubbed, plain = runs[0.3], runs[0.0]
    assert rubbed["impactor_friction_energy"][-1] > 0.01 * kinetic
    assert "impactor_friction_energy" not in plain
    drift = {mu: np.ptp(h["energy_balance"]) for mu, h in runs.items()}
    assert drift[0.3] < 1e-5 * kinetic and drift[0.3] < 1.5 * drift[0.0] + 1e-9 * kinetic
    assert rubbed["impact_work"][-1] != plain["impact_work"][-1]
