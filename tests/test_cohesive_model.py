"""A single cohesive element inside the models: an ESL cell strongly refined from the start, and
the cohesive element of a two-layer LW mesh, pulled along prescribed opening paths through the
whole assembly (maps, gather/scatter, damage history, signs) and through the explicit solver."""

import copy
import math

import numpy as np
import pytest
from helpers import COHESIVE_LAW

from fenics_adaptive.materials.cohesive import critical_energy, traction_separation_curve
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.materials import CohesiveLaw
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit

LAW = dict(COHESIVE_LAW)  # this module's own copy
CELL = {
    "mesh": {"length": 1.0, "width": 1.0, "nx": 1, "ny": 1},
    "materials": {
        "stiff": {"E1": 1e7, "E2": 1e7, "G12": 4e6, "nu12": 0.25, "nu23": 0.25, "rho": 1.6e-9}
    },
    "laminate": {"material": "stiff", "ply_thickness": 0.5, "angles": [0, 0]},
    "cohesive": LAW,
    "clamp": [{"face": "bottom"}],
    "prescribed": [{"face": "top", "component": "z", "velocity": 2000.0, "rise_time": 1e-6}],
    "solver": {"end_time": 5e-5},
    "output": {
        "interval": 1e-6,
        "displacement_face": "top",
        "reaction_face": "top",
        "component": "z",
    },
}


def single_cohesive(kind: str, law: dict = LAW, insert: bool = False) -> dict:
    data = copy.deepcopy(CELL)
    data["cohesive"] = dict(law)
    if insert:  # an insert film over the whole interface
        data["delamination"] = [{"interface": 1, "x_min": 0.0, "x_max": 1.0}]
    if kind == "adaptive":
        data["model"] = {"kind": "adaptive"}
        data["interfaces"] = {"delaminate": [1], "initial": "strong"}
    else:
        data["model"] = {"kind": "layerwise", "points_per_ply": 2}
        data["mesh"]["layers"] = [1, 1]
        data["interfaces"] = {"delaminate": [1]}
    data["model"]["check_units"] = False  # plies of 10 TPa: near-rigid blocks on purpose
    return data


class Kinematic:
    """Drive a structure by setting every node: lower side (bottom base nodes and the cohesive
    element's lower face) at rest, upper side moved by the opening. The plies move rigidly, so
    the only force is the cohesive one; the upper nodes' internal force is traction x area."""

    def __init__(self, kind: str, law: dict = LAW, insert: bool = False):
        self.structure = build_structure(parse_config(single_cohesive(kind, law, insert)))
        s = self.structure
        assert len(s.cohesive) == 1
        nodes = s.cohesive.nodes[0]
        self.upper = list(nodes[4:])
        if kind == "adaptive":
            self.upper += list(s.top_local[0])
        else:
            cells = s.base.V.dofmap.list
            self.upper = sorted(set(self.upper) | set(cells[1][:].tolist()) - set(nodes[:4]))
            self.upper = [n for n in self.upper if s.X_base[n, 2] > 0.25]

    def force(self, opening: np.ndarray) -> np.ndarray:
        s = self.structure
        for block in s.blocks:
            block.u.array[:] = 0.0
        for node in self.upper:
            if node < s.n_base:
                s.base.u.x.array.reshape(-1, 3)[node] = opening
            else:
                s.extra.vectors["u"].array.reshape(-1, 3)[node - s.n_base] = opening
        s.internal_force()
        fb = s.f_base.array.reshape(-1, 3)
        fx = s.f_extra.array.reshape(-1, 3)
        return sum(fb[n] if n < s.n_base else fx[n - s.n_base] for n in self.upper)

    def pull(self, path: np.ndarray) -> tuple[np.ndarray, float]:
        """Tractions along the path and the work done (per unit area, area = 1 mm^2)."""
        tractions = np.array([self.force(d) for d in path])
        work = np.sum(0.5 * (tractions[1:] + tractions[:-1]) * np.diff(path, axis=0))
        return tractions, work


def proportional_path(mixity: float, law: CohesiveLaw, points: int = 3000) -> np.ndarray:
    beta = math.sqrt(mixity / (1.0 - mixity)) if mixity < 1 else math.inf
    direction = np.array([math.sin(math.atan(beta)), 0.0, math.cos(math.atan(beta))])
    final = 2.0 * max(law.GIc, law.GIIc) / min(law.N, law.S) * 1.5
    return np.linspace(0.0, final, points)[:, None] * direction


@pytest.mark.parametrize("kind", ["adaptive", "layerwise"])
def test_an_insert_film_carries_no_tension_or_shear_but_keeps_its_faces_apart(kind):
    """[[delamination]]: the element starts failed (no traction when opened or sheared, no
    energy dissipated), and closing it meets the undamaged normal penalty: the faces of an
    insert cannot interpenetrate, and slide without friction."""
    law = CohesiveLaw.from_mapping(LAW)
    model = Kinematic(kind, insert=True)
    cohesive = model.structure.cohesive
    assert cohesive.failed().all() and cohesive.inserted().all()
    for opening in ([0.0, 0.0, 0.01], [0.01, 0.0, 0.0], [0.0, 0.02, 0.005], [0.03, 0.0, -1e-4]):
        opening = np.array(opening)
        t = model.force(opening)
        normal = law.K_n * min(opening[2], 0.0)
        assert np.abs(t - [0.0, 0.0, normal]).max() <= 1e-12 * law.K_n * 0.01, opening
    assert cohesive.dissipated_energy() == 0.0
    # an intact element under the same closing carries the same compression
    intact = Kinematic(kind)
    closing = np.array([0.0, 0.0, -1e-4])
    assert model.force(closing)[2] == pytest.approx(intact.force(closing)[2], rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["adaptive", "layerwise"])
@pytest.mark.parametrize("mixity", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_dissipated_energy_and_traction_separation(kind, mixity):
    law = CohesiveLaw.from_mapping(LAW)
    model = Kinematic(kind)
    path = proportional_path(mixity, law)
    tractions, work = model.pull(path)
    stored = model.structure.internal_forces.energies()[1]
    assert stored == pytest.approx(0.0, abs=1e-12)  # fully separated
    assert work == pytest.approx(critical_energy(law, mixity), rel=0.01)
    expected, _, _ = traction_separation_curve(law, path)
    # the element's local frame: t1 along x, t2 along y, n along z, so the law's local
    # tractions are the global ones here
    peak = np.abs(expected).max()
    assert np.abs(tractions - expected).max() < 1e-9 * peak


@pytest.mark.parametrize("kind", ["adaptive", "layerwise"])
def test_unloading_follows_the_damaged_secant_and_compression_does_not_penetrate(kind):
    law = CohesiveLaw.from_mapping(LAW)
    model = Kinematic(kind)
    onset = law.N / law.K_n
    final = 2 * law.GIc / law.N
    peak_opening = 0.5 * (onset + final)
    up = np.linspace(0, peak_opening, 400)
    down = np.linspace(peak_opening, 0, 400)[1:]
    path = np.concatenate([up, down])[:, None] * np.array([0.0, 0.0, 1.0])
    tractions, work = model.pull(path)
    damage = final * (peak_opening - onset) / (peak_opening * (final - onset))
    secant = (1 - damage) * law.K_n
    unloading = tractions[400:, 2]
    assert np.allclose(unloading, secant * path[400:, 2], rtol=1e-9, atol=1e-12)
    # energy lost on the cycle = dissipated so far
    dissipated = law.GIc * (peak_opening - onset) / (final - onset)
    assert work == pytest.approx(dissipated, rel=1e-3)
    # compression: the undamaged penalty, however damaged the interface is
    for closing in (-1e-4, -1e-3):
        t = model.force(np.array([0.0, 0.0, closing]))
        assert t[2] == pytest.approx(law.K_n * closing, rel=1e-12)


@pytest.mark.slow
def test_explicit_pull_dissipates_gic():
    """The solver pulls the top face of the refined cell up (mode I); once the interface has
    failed, the dissipated-energy column holds GIc x area."""
    data = single_cohesive("adaptive")
    config = parse_config(data)
    structure = build_structure(config)
    stats = explicit.run(structure, config.solver, config.probe)
    final = stats.history[-1]
    assert final.displacement > 2 * 2 * LAW["GIc"] / LAW["N"]  # well past full separation
    assert final.dissipated_energy == pytest.approx(LAW["GIc"] * 1.0, rel=0.01)
    work = max(r.external_work for r in stats.history)
    assert max(abs(r.energy_balance) for r in stats.history) < 1e-4 * work
