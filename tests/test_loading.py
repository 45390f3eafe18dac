"""Time curves and prescribed motions."""

import itertools

import numpy as np
import pytest

from fenics_adaptive.settings.loads import Amplitude, PrescribedMotion

CURVES = [
    Amplitude.ramp(2e-5),
    Amplitude.ramp(2e-5, smooth=False),
    Amplitude((0.0, 1.0, 3.0, 4.0), (0.5, 2.0, -1.0, 0.0), smooth=True),
    Amplitude((0.5, 1.0, 3.0), (0.5, 2.0, -1.0)),
]


def numerical_integral(amplitude: Amplitude, t: float) -> float:
    """Composite Simpson on every piece between knots (exact for the cubic smoothstep)."""
    knots = sorted({0.0, t, *[k for k in amplitude.times if 0.0 < k < t]})
    total = 0.0
    for a, b in itertools.pairwise(knots):
        x = np.linspace(a, b, 201)
        y = np.array([amplitude(s) for s in x])
        h = (b - a) / 200
        total += h / 3 * (y[0] + y[-1] + 4 * y[1:-1:2].sum() + 2 * y[2:-1:2].sum())
    return total


@pytest.mark.parametrize("amplitude", CURVES)
@pytest.mark.parametrize("t", [0.0, 0.3e-5, 1e-5, 3e-5, 0.7, 2.0, 3.5, 5.0])
def test_integral_is_exact(amplitude, t):
    assert amplitude.integral(t) == pytest.approx(numerical_integral(amplitude, t), abs=1e-12)


def test_smooth_ramp_has_zero_rate_at_both_ends():
    ramp = Amplitude.ramp(1.0)
    h = 1e-6
    assert ramp(0.5) == pytest.approx(0.5)
    assert (ramp(h) - ramp(0.0)) / h < 1e-5
    assert (ramp(1.0) - ramp(1.0 - h)) / h < 1e-5
    assert ramp(2.0) == 1.0


def test_velocity_motion_integrates_its_amplitude():
    motion = PrescribedMotion("x1", "z", "velocity", 100.0, Amplitude.ramp(1e-3))
    # smooth velocity ramp: half the rise time is lost against the full velocity
    assert motion.displacement(3e-3) == pytest.approx(100.0 * (3e-3 - 0.5e-3))
