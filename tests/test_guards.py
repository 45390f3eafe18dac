"""Physics guards: an inverted element, a broken energy balance and an impactor penalty the time
step cannot carry stop the run with one line (CLI exit status 1 or 2, summary status failed).

Units: N, mm, s, tonne.
"""

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import esl_model, highest_frequency, toml_text
from mpi4py import MPI

from fenics_adaptive.model import loading
from fenics_adaptive.model.forces import Contributor, ForceKind
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.adaptivity import Interfaces
from fenics_adaptive.settings.config import load_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.loads import Amplitude, PrescribedMotion, clamp
from fenics_adaptive.simulation import build_structure
from fenics_adaptive.solver import explicit, guards

DATA = Path(__file__).parent / "data"
ROOT = Path(__file__).parents[1]


def small_beam(**changes) -> dict:
    data = tomllib.loads((DATA / "small_beam.toml").read_text())
    for dotted, value in changes.items():
        table, key = dotted.split(".")
        data.setdefault(table, {})[key] = value
    return data


def run_cli(tmp_path: Path, data: dict) -> tuple[subprocess.CompletedProcess, dict]:
    config = tmp_path / "case.toml"
    config.write_text(toml_text(data))
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "fenics_adaptive", "run", str(config), "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
    )
    summary = out / "summary.json"
    return result, json.loads(summary.read_text()) if summary.exists() else {}


# ------------------------------------------------------------------ inversion
def crush(data: dict, depth: float) -> dict:
    """The beam's bottom clamped, its top face pushed down ``depth`` (mm) in 20 us."""
    data["clamp"] = [{"face": "bottom"}]
    data["prescribed"] = [
        {
            "face": "top",
            "component": "z",
            "displacement": -depth,
            "rise_time": 2.0e-5,
            "profile": "smooth",
        }
    ]
    data["solver"]["end_time"] = 4.0e-5
    data["output"].update(displacement_face="top", reaction_face="top", interval=2.0e-6)
    data["output"].pop("fields_interval", None)
    return data


@pytest.mark.slow
@pytest.mark.parametrize("kinematics", ["small", "finite"])
def test_a_crushed_beam_stops_with_the_inverted_cell(tmp_path, kinematics):
    """Pressing the top face of a 2 mm beam 3 mm down (through its bottom) inverts every cell:
    exit status 1, one line naming the cell, its centroid, the ply, the point and the time;
    summary status failed. The same press to 1 mm does not trip it."""
    data = crush(small_beam(), 3.0)
    data["model"]["kinematics"] = kinematics
    result, summary = run_cli(tmp_path, data)
    assert result.returncode == 1, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    line = lines[0]
    assert "element inverted: cell " in line and "centroid" in line and "ply " in line
    assert "integration point (xi, eta, zeta)" in line and "det F = " in line
    t = float(line.split("t = ")[1].split(" s")[0])
    # the top face passes the bottom (u_z = -2 mm) at about 60 % of the 20 us ramp; the check
    # runs every 64 steps and on output steps (2 us)
    assert 8e-6 < t < 2.0e-5
    assert summary["status"] == "failed" and "ElementInverted" in summary["error"]


@pytest.mark.slow
def test_a_pressed_but_not_inverted_beam_completes(tmp_path):
    data = crush(small_beam(), 1.0)
    result, summary = run_cli(tmp_path, data)
    assert result.returncode == 0, result.stderr
    assert summary["status"] == "completed"


def inverted_state(structure: Structure, cell: int, depth: float) -> None:
    """Push the top nodes of one owned cell ``depth`` (mm) below its bottom nodes."""
    u = structure.base.u.x.array.reshape(-1, 3)
    u[:] = 0.0
    thickness = structure.laminate.thickness
    u[structure.top_local[cell], 2] = -(thickness + depth)


def test_the_check_names_the_cell_on_every_kind_of_element():
    """ESL (UFL) cells, subelements of refined cells and LW cells: the check finds the one
    cell whose top was pushed through its bottom, names it, and finds nothing in the
    undeformed state."""
    comm = MPI.COMM_WORLD
    # ESL
    model = esl_model([0, 90, 90, 0], 10.0, 1.0, 5, 1)
    esl = Structure(model, loading.resolve(model, clamp("x0"), []))
    # adaptive, interface 2 strong from the start: two subelements per cell + cohesive
    model = esl_model([0, 90, 90, 0], 10.0, 1.0, 5, 1)
    adaptive = Structure(
        model,
        loading.resolve(model, clamp("x0"), []),
        interfaces=Interfaces(refine=(2,), delaminate=(2,)),
    )
    adaptive.refine([(c, 2, InterfaceState.STRONG) for c in range(model.n_owned_cells)])
    for structure in (esl, adaptive):
        guard = guards.InversionGuard(structure)
        assert guard.check(0.0) is None
        cell = 3
        inverted_state(structure, cell, 0.1)
        structure.follow_border()
        message = guard.check(1.5e-6)
        assert message is not None
        # the pushed nodes are shared: this cell and its neighbours along x have inverted
        moved = set(structure.top_local[cell].tolist())
        touched = [
            c for c in range(len(structure.top_local)) if moved & set(structure.top_local[c])
        ]
        named = int(
            message.split(" of cell " if "subelement" in message else ": cell ")[1].split()[0]
        )
        assert named in {int(structure.original_cell[c]) for c in touched}
        assert message.startswith("t = 1.5e-06 s: element inverted")
        if structure is adaptive:
            assert "subelement (plies" in message
    assert comm.size >= 1


def test_the_check_covers_layerwise_cells(tmp_path):
    config = load_config(DATA / "tcb_layerwise.toml")
    structure = build_structure(config, MPI.COMM_WORLD)
    guard = guards.InversionGuard(structure)
    assert guard.check(0.0) is None
    u = structure.base.u.x.array.reshape(-1, 3)
    cell = 7
    u[structure.top_local[cell], 2] -= 2.0 * config.laminate.thickness
    message = guard.check(0.0)
    assert message is not None and "element inverted: cell " in message
    moved = set(structure.top_local[cell].tolist())
    touched = [c for c in range(len(structure.top_local)) if moved & set(structure.top_local[c])]
    named = int(message.split(": cell ")[1].split()[0])
    assert named in {int(structure.original_cell[c]) for c in touched}


def test_reference_orientation_does_not_matter():
    """A mirrored (left-handed) reference hexahedron is not 'inverted'; inverting it is."""
    X = np.array([[k & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)], dtype=float)
    X[:, 0] *= -1.0  # det J < 0 in the reference
    nodes = np.arange(8, dtype=np.int32)[None, :]
    sign = guards.reference_orientation(nodes, X, np.zeros((0, 3)))
    assert sign[0] == -1.0
    rule_offsets = np.array([0, 2], dtype=np.int64)
    zeta = np.array([0.2, 0.8])
    position = np.zeros(2, dtype=np.int64)
    lines = guards.rule_lines(rule_offsets, position)
    positions = np.array([[0.5, 0.5]])
    none = np.zeros((0, 3))
    scratch = (np.empty((8, 3)), np.empty((8, 3)))
    u = np.zeros((8, 3))
    rule_of = np.zeros(1, np.int64)
    args = (nodes, rule_of, sign, *lines, zeta, position, positions, X, none)
    e, _, _ = guards.first_inverted_point(*args, u, none, *scratch)
    assert e == -1
    u[4:, 2] = -0.5  # squashed to half its height: not inverted
    e, _, _ = guards.first_inverted_point(*args, u, none, *scratch)
    assert e == -1
    u[4:, 2] = -1.5  # top through bottom
    e, p, det = guards.first_inverted_point(*args, u, none, *scratch)
    assert e == 0 and p == 0
    assert e == 0 and det <= 0.0


# ------------------------------------------------------------------ energy balance
def test_energy_guard_rule():
    assert not guards.energy_error(0.04, 1.0, 0.05, 1000)
    assert guards.energy_error(0.06, 1.0, 0.05, 1000)
    assert guards.energy_error(-0.06, 1.0, 0.05, 1000)
    assert guards.energy_error(float("nan"), 1.0, 0.05, 0)
    # the first steps never trip it (the start-up error of an impulsive start)
    assert not guards.energy_error(0.9, 1.0, 0.05, guards.ENERGY_MIN_STEPS - 1)


@pytest.mark.slow
def test_a_huge_load_is_stopped(tmp_path):
    """The issue's 1e12 N tip load (displacement 2.4e10 mm, status completed before): now the
    run fails, with one line."""
    data = small_beam()
    data.pop("prescribed")
    data["load"] = [
        {"face": "x1", "force": [0.0, 0.0, 1.0e12], "rise_time": 1.0e-5, "profile": "smooth"}
    ]
    data["solver"]["end_time"] = 1.0e-4
    data["output"]["reaction_face"] = "x0"
    data["output"].pop("fields_interval", None)
    result, summary = run_cli(tmp_path, data)
    assert result.returncode == 1, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert summary["status"] == "failed"
    # what catches it: the beam is folded through itself long before anything overflows
    assert "ElementInverted" in summary["error"], summary["error"]


class UniformPush(Contributor):
    """A uniform z force (N per base node) on every owned node, of the given kind: EXTERNAL is
    booked as external work; CONTACT as the work of an impactor that this one does not report,
    so its work is energy the balance cannot account for."""

    name = "push"

    def __init__(self, kind: ForceKind, force: float, n_owned: int):
        self.kind, self.force, self.n_owned = kind, force, n_owned

    def add_force(self, t, f_base, f_extra):
        f_base[2 : self.n_owned : 3] += self.force


def pushed_beam_run(kind: ForceKind, **settings) -> explicit.RunStats:
    """The clamped [0/90/90/0] beam (20 x 1 mm, 8 cells) with its tip pulled 0.05 mm up over
    100 us and a uniform push of 2e-4 N per node (a few % of the tip's work)."""
    model = esl_model([0, 90, 90, 0], 20.0, 1.0, 8, 1)
    tip = PrescribedMotion("x1", "z", "displacement", 0.05, Amplitude.ramp(1e-4))
    structure = Structure(model, loading.resolve(model, [*clamp("x0"), tip], []))
    push = UniformPush(kind, 2e-4, structure.blocks[0].n_owned)
    solver_settings = explicit.SolverSettings(end_time=1.5e-4, output_interval=5e-6, **settings)
    return explicit.run(
        structure, solver_settings, explicit.Probe("x1", "x1", "z"), contributors=[push]
    )


def judged_shares(stats: explicit.RunStats) -> np.ndarray:
    """|energy balance - its value at t = 0| / the largest energy so far, on the rows the
    energy guard judges (the balance starts at the first step's impulse: the push acts at
    t = 0)."""
    rows = stats.history
    largest = np.maximum.accumulate(
        [
            guards.largest_energy(
                r.external_work, r.impact_work, r.kinetic_energy, r.internal_energy
            )
            for r in rows
        ]
    )
    return np.array(
        [
            abs(r.energy_balance - rows[0].energy_balance) / largest[k]
            for k, r in enumerate(rows)
            if r.time >= (guards.ENERGY_MIN_STEPS + 1) * stats.time_step
        ]
    )


@pytest.mark.slow
def test_energy_limit_from_the_settings_stops_a_run():
    """A force whose work nobody books is energy from nowhere: booked (EXTERNAL) the balance
    closes to round-off; unbooked (a CONTACT force that reports no impact work) the run
    completes with the default limit, which its share stays below, and fails with a limit
    below its worst share; the message names the time, the error and the largest energy."""
    booked = judged_shares(pushed_beam_run(ForceKind.EXTERNAL))
    assert booked.max() < 1e-12
    unbooked = judged_shares(pushed_beam_run(ForceKind.CONTACT))
    worst = unbooked.max()
    assert 1e-4 < worst < explicit.SolverSettings(1.0, 1.0).energy_error_limit
    with pytest.raises(explicit.EnergyBalanceError, match=r"t = .* s \(step \d+\): energy balance"):
        pushed_beam_run(ForceKind.CONTACT, energy_error_limit=worst / 3)


# ------------------------------------------------------------------ impactor penalty
@pytest.mark.slow
def test_an_impactor_penalty_the_step_cannot_carry_is_refused(tmp_path):
    data = tomllib.loads((ROOT / "demos" / "plate_impact.toml").read_text())
    data["impactor"]["penalty"] = 1.0e12
    config = tmp_path / "impact.toml"
    config.write_text(toml_text(data))
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "fenics_adaptive",
            "run",
            str(config),
            "--out",
            str(tmp_path / "out"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
    )
    assert result.returncode == 2, result.stderr
    line = result.stderr.strip()
    assert "impactor.penalty" in line and "largest stable penalty is" in line
    assert len(line.splitlines()) == 1
    assert not (tmp_path / "out" / "history.csv").exists()


def test_an_unstable_step_is_stopped_before_it_overflows():
    """A step 1 % above the stability limit (forced past the check) makes the highest mode grow
    from round-off by about 1.2 per step: the run stops as Diverged (the kinetic energy
    dwarfs the work put in, or an element folds), with finite numbers, well before 2000 steps
    (the energy identity of the scheme holds at any step: the balance guard cannot see it)."""

    model = esl_model([0, 90, 90, 0], 20.0, 1.0, 8, 1)
    tip = PrescribedMotion("x1", "z", "displacement", 0.05, Amplitude.ramp(1e-4))
    loads = loading.resolve(model, [*clamp("x0"), tip], [])
    dt = 1.01 * 2.0 / highest_frequency(model, loads.constrained)
    settings = explicit.SolverSettings(end_time=2000 * dt, output_interval=dt)
    with pytest.raises(explicit.Diverged) as failure:
        explicit.run(
            Structure(model, loads), settings, explicit.Probe("x1", "x1", "z"), time_step=dt
        )
    message = str(failure.value)
    assert "kinetic energy" in message or "inverted" in message, message
    step = int(re.search(r"\(step (\d+)\)", message).group(1))
    assert step < 600, message
    numbers = [float(x) for x in re.findall(r"(-?\d+\.?\d*e[+-]?\d+|-?\d+\.\d+) mJ", message)]
    assert numbers and np.all(np.isfinite(numbers)), message
