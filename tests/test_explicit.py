"""The lumped-mass central-difference solver: free vibration (period and energy), the stable
time step against the true highest frequency, and quasi-static agreement with the static solver.

Units: N, mm, s, tonne.
"""

import math
import re

import numpy as np
import pytest
from dolfinx import fem
from helpers import (
    CROSS_PLY,
    cantilever_first_period,
    crossing_times,
    esl_model,
    highest_frequency,
)

from fenics_adaptive.errors import InputError
from fenics_adaptive.model import loading
from fenics_adaptive.model.loading import face_dofs
from fenics_adaptive.model.structure import Structure
from fenics_adaptive.settings.loads import Amplitude, FaceLoad, PrescribedMotion, clamp
from fenics_adaptive.solver import explicit
from fenics_adaptive.solver.observers import Observer
from fenics_adaptive.solver.static import solve_static

LENGTH, WIDTH = 50.0, 2.0


def cantilever(angles=(0,) * 8, nx=20):
    return esl_model(list(angles), LENGTH, WIDTH, nx, 1)


def first_bending_period(model) -> float:
    """The cantilever's Euler-Bernoulli first period (s)."""
    return cantilever_first_period(model.layer_laminates[0], WIDTH, LENGTH)


@pytest.mark.slow
def test_free_vibration_period_and_energy():
    """Released from its static deflection under a tip load, the [0]8 cantilever swings with the
    beam-theory period (within 3 %) and keeps its energy (drift below 0.5 % over 20 periods)."""
    model = cantilever()
    motions = clamp("x0")
    tip_load = FaceLoad("x1", (0.0, 0.0, -1.0), Amplitude.constant())
    static = loading.resolve(model, motions, [tip_load])
    u0 = solve_static(model, motions, static, 0.0)
    f_ext = np.zeros_like(u0)
    static.external_force(0.0, f_ext)
    n = model.n_owned_dofs
    strain_energy = 0.5 * np.dot(f_ext[:n], u0[:n])

    period = first_bending_period(model)
    free = loading.resolve(model, motions, [])
    settings = explicit.SolverSettings(end_time=20.3 * period, output_interval=period / 50)
    stats = explicit.run(
        Structure(model, free), settings, explicit.Probe("x1", "x0", "z"), initial_displacement=u0
    )
    t = [r.time for r in stats.history]
    up = crossing_times(t, [r.displacement for r in stats.history])
    assert len(up) == 20
    measured = (up[-1] - up[0]) / (len(up) - 1)
    assert measured == pytest.approx(period, rel=0.03)

    total = np.array([r.kinetic_energy + r.internal_energy for r in stats.history])
    assert np.abs(total).max() < 0.005 * strain_energy
    kinetic = np.array([r.kinetic_energy for r in stats.history])
    assert kinetic.max() == pytest.approx(strain_energy, rel=0.05)  # it really swings


@pytest.mark.slow
def test_stable_time_step_estimate_is_safe_and_sharp():
    """L_e / c is below the exact limit 2 / omega_max of the discrete system, but not by much;
    the scheme is stable just below 2 / omega_max and blows up just above."""
    model = cantilever(CROSS_PLY, nx=10)
    motions = clamp("x0")
    loads = loading.resolve(model, motions, [])
    critical = 2.0 / highest_frequency(model, loads.constrained)
    estimate, _ = Structure(model, loads).stable_time_step()
    assert 0.5 * critical < estimate <= critical

    u0 = np.random.default_rng(1).standard_normal(len(model.u.x.array)) * 1e-3
    probe = explicit.Probe("x1", "x0", "z")
    amplitude = []

    class Amplitude(Observer):
        def on_history(self, row):
            amplitude.append(np.abs(model.u.x.array).max())

    steps = 1500
    # at 0.98 x the critical step the full-step kinetic energy v_n = v_{n-1/2} + dt/2 a_n of the
    # highest modes (a random field excites them) is off by O(1): the energy guard would stop
    # the run; only its stability is tested here
    below = explicit.SolverSettings(
        end_time=steps * 0.98 * critical, output_interval=1e-6, energy_error_limit=math.inf
    )
    explicit.run(
        Structure(model, loads),
        below,
        probe,
        observers=[Amplitude()],
        time_step=0.98 * critical,
        initial_displacement=u0,
    )
    assert max(amplitude) < 10 * np.abs(u0).max()
    above = explicit.SolverSettings(end_time=steps * 1.2 * critical, output_interval=1e-6)
    with pytest.raises(explicit.Diverged) as failure:
        explicit.run(
            Structure(model, loads),
            above,
            probe,
            time_step=1.2 * critical,
            initial_displacement=u0,
        )
    # the message says when and where (the node moving fastest), and what to suspect
    message = str(failure.value)
    assert "t = " in message and "time step" in message
    assert re.search(r"at cell \d+, base node at \(", message), message


@pytest.mark.slow
def test_quasi_static_explicit_matches_static_solution():
    """A slow, damped tip-displacement ramp ends at the static reaction force (two independent
    paths: explicit dynamics vs a direct linear solve)."""
    model = cantilever(CROSS_PLY, nx=20)
    period = first_bending_period(model)
    pull = PrescribedMotion("x1", "z", "displacement", -0.4, Amplitude.ramp(3 * period))
    motions = [*clamp("x0"), pull]
    loads = loading.resolve(model, motions, [])
    settings = explicit.SolverSettings(
        end_time=5 * period, output_interval=period / 10, mass_damping=2.0 / period
    )
    stats = explicit.run(Structure(model, loads), settings, explicit.Probe("x1", "x1", "z"))

    solve_static(model, motions, loads, settings.end_time)
    f = fem.Function(model.V).x
    model.internal_force(f)
    static_reaction = f.array[face_dofs(model, "x1", "z")].sum()
    final = stats.history[-1]
    assert final.displacement == pytest.approx(-0.4, rel=1e-12)
    assert final.reaction_force == pytest.approx(static_reaction, rel=0.01)
    # energy: what the actuator put in is stored, swinging or damped out, nothing else
    work = max(abs(r.external_work) for r in stats.history)
    assert max(abs(r.energy_balance) for r in stats.history) < 1e-6 * work
    assert final.damping_energy > 0


def test_forcing_one_and_a_half_times_the_stable_step_is_refused():
    model = cantilever(CROSS_PLY, nx=10)
    settings = explicit.SolverSettings(end_time=1e-4, output_interval=1e-5)
    structure = Structure(model, loading.resolve(model, clamp("x0"), []))
    dt, stable, _ = explicit.choose_time_step(structure, settings)
    assert dt == stable
    forced = explicit.SolverSettings(end_time=1e-4, output_interval=1e-5, time_step=1.5 * stable)
    with pytest.raises(InputError, match=r"solver\.time_step"):
        explicit.choose_time_step(structure, forced)
