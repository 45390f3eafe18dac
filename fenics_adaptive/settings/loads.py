"""Loads as the config gives them: time curves, clamps, prescribed motions, face loads and the
impactor (standard library and numpy only; ``model.loading`` resolves them to the DOFs of a model,
``model.contact`` makes the impactor act).

Units: N, mm, s, tonne. A face is named by its group in the mesh (``fenics_adaptive.meshes.beam``:
x0, x1, top, x1_layer3, ...). Components are "x", "y", "z".
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from fenics_adaptive.settings.kinds import ImpactorShape, MotionKind, RigidMotion

# a displacement component as the config names it -> its index among a node's three DOFs
COMPONENTS = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Amplitude:
    """Dimensionless scale factor of time: piecewise between the points (times, values), constant
    before the first and after the last. ``smooth`` joins the points with the C1 smoothstep
    3 s^2 - 2 s^3 instead of straight lines (zero rate at every point: no velocity jumps)."""

    times: tuple[float, ...]
    values: tuple[float, ...]
    smooth: bool = False

    def __post_init__(self) -> None:
        if len(self.times) != len(self.values) or len(self.times) < 1:
            raise ValueError("amplitude: need as many values as times, at least one")
        if any(not math.isfinite(t) for t in self.times + self.values):
            raise ValueError("amplitude: times and values must be finite")
        if any(b < a for a, b in itertools.pairwise(self.times)):
            raise ValueError("amplitude: times must not decrease")

    @classmethod
    def ramp(cls, rise_time: float, smooth: bool = True) -> Amplitude:
        """0 at t = 0 up to 1 at t = rise_time, then held."""
        if not rise_time > 0:
            raise ValueError(f"amplitude: rise_time must be > 0 s (got {rise_time})")
        return cls((0.0, float(rise_time)), (0.0, 1.0), smooth)

    @classmethod
    def constant(cls, value: float = 1.0) -> Amplitude:
        return cls((0.0,), (float(value),))

    def _segment(self, t: float) -> tuple[int, float] | None:
        i = bisect.bisect_right(self.times, t) - 1
        if i < 0 or i >= len(self.times) - 1:
            return None
        t0, t1 = self.times[i], self.times[i + 1]
        return i, (t - t0) / (t1 - t0) if t1 > t0 else 1.0

    def __call__(self, t: float) -> float:
        segment = self._segment(t)
        if segment is None:
            return self.values[0] if t < self.times[0] else self.values[-1]
        i, s = segment
        if self.smooth:
            s = s * s * (3.0 - 2.0 * s)
        return self.values[i] + (self.values[i + 1] - self.values[i]) * s

    def integral(self, t: float) -> float:
        """Integral of the amplitude from 0 to t (s): a velocity amplitude's displacement.
        Exact: a straight segment integrates to its mean, a smoothstep segment from v0 to v1
        over a fraction x of its length T to T (v0 x + (v1 - v0) (x^3 - x^4 / 2))."""
        if t <= 0.0:
            return 0.0
        knots = self._knot_integrals
        first = self.times[0]
        if t <= first:
            return self.values[0] * t
        i = min(bisect.bisect_right(self.times, t) - 1, len(self.times) - 1)
        if i == len(self.times) - 1:
            return knots[-1] + self.values[-1] * (t - self.times[-1])
        length = self.times[i + 1] - self.times[i]
        x = (t - self.times[i]) / length
        v0, v1 = self.values[i], self.values[i + 1]
        if self.smooth:
            piece = length * (v0 * x + (v1 - v0) * (x**3 - 0.5 * x**4))
        else:
            piece = length * x * (v0 + 0.5 * (v1 - v0) * x)
        return knots[i] + piece

    @functools.cached_property
    def _knot_integrals(self) -> list[float]:
        """Integral from 0 to each knot time."""
        first = max(self.times[0], 0.0)
        out = [self.values[0] * first]
        for i in range(len(self.times) - 1):
            length = self.times[i + 1] - self.times[i]
            out.append(out[-1] + 0.5 * length * (self.values[i] + self.values[i + 1]))
        return out


@dataclass(frozen=True)
class PrescribedMotion:
    """Displacement of ``component`` of every node on ``face`` (or only those with x in
    ``x_range``):
    value * amplitude(t) when ``kind`` is "displacement" (mm), value * integral of amplitude
    when it is "velocity" (mm/s). A clamp is a displacement of 0 in all components."""

    face: str
    component: str
    kind: MotionKind
    value: float
    amplitude: Amplitude
    x_range: tuple[float, float] | None = None  # only the face's nodes with x in it (mm): a
    # line (x, x) or a pad (x_min, x_max) of a support or a load
    key: str = field(default="", compare=False)  # the config key that made it (for errors)

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", MotionKind(self.kind))  # frozen: set once, here

    @property
    def constant(self) -> bool:
        """Its displacement never changes (a clamp, a held displacement)."""
        if self.kind == MotionKind.DISPLACEMENT:
            return self.value == 0.0 or len(self.amplitude.times) == 1
        return self.value == 0.0

    def displacement(self, t: float) -> float:
        if self.kind == MotionKind.DISPLACEMENT:
            return self.value * self.amplitude(t)
        return self.value * self.amplitude.integral(t)


@dataclass(frozen=True)
class Region:
    """An x, y range (mm) that picks cells or facets by their centroid, edges included; the
    default is everything."""

    x_min: float = -math.inf
    x_max: float = math.inf
    y_min: float = -math.inf
    y_max: float = math.inf

    def holds(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Which of the centroids (x, y) (mm) lie in the region."""
        return (x >= self.x_min) & (x <= self.x_max) & (y >= self.y_min) & (y <= self.y_max)

    def __str__(self) -> str:
        return f"x in [{self.x_min:g}, {self.x_max:g}], y in [{self.y_min:g}, {self.y_max:g}] mm"


@dataclass(frozen=True)
class FaceLoad:
    """A load on a face, times amplitude(t): a total force ``force`` (N, vector) spread as a
    uniform traction, or a ``pressure`` (MPa, normal to the face; positive pushes into the
    body, against the outward normal) shaped along x by ``distribution``. ``region`` limits
    it to the face's facets whose centroid lies in it.

    ``distribution``: (x (mm), factor) points, x increasing; the pressure at x is ``pressure``
    times the factor interpolated linearly, held at the end values outside the points (None:
    a factor of 1 everywhere)."""

    face: str
    force: tuple[float, float, float] | None
    amplitude: Amplitude
    key: str = field(default="", compare=False)  # the config key that made it (for errors)
    pressure: float | None = None
    distribution: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    region: Region = field(default_factory=Region)

    def __post_init__(self) -> None:
        if (self.force is None) == (self.pressure is None):
            raise ValueError("a face load has either a force or a pressure")
        if self.distribution is not None and self.pressure is None:
            raise ValueError("a distribution shapes a pressure")

    def factor(self, x):
        """The distribution's factor at x (mm, a number or an array)."""
        if self.distribution is None:
            return np.ones_like(x, dtype=float)
        return np.interp(x, *self.distribution)


def clamp(face: str) -> list[PrescribedMotion]:
    """The motions that hold every displacement component of ``face`` at zero."""
    return [
        PrescribedMotion(face, c, MotionKind.DISPLACEMENT, 0.0, Amplitude.constant(0.0))
        for c in COMPONENTS
    ]


@dataclass(frozen=True)
class RigidBody:
    """A rigid loading body ([[rigid]], or the [impactor]): a sphere of ``radius`` (mm) about
    its centre, a cylinder of ``radius`` whose axis runs along ``axis`` ("x" or "y") through
    the centre, or a plane through the centre with the unit ``normal`` (pointing from the
    plane to the structure; ``radius`` 0), in penalty contact with the nodes of ``face``
    ("top", "bottom", or "all": every node of the laminate, extra nodes included), with
    Coulomb ``friction`` (the coefficient; 0: frictionless). ``position`` (mm): the centre at
    t = 0. ``motion``:

    - FIXED: held there (a support);
    - PRESCRIBED: moved by ``displacement`` (mm, vector) x amplitude(t), or by ``velocity``
      (mm/s, vector) x the integral of amplitude (a loading nose);
    - FREE: a body of ``mass`` (tonne) starting at ``velocity`` (mm/s), moved by the contact
      forces (an impactor);
    - LEVER: the saddle of the ``Lever``, which sets its height.

    ``penalty``: N/mm per node (None: from the laminate, ``model.contact``). ``name``: the
    body's history columns (``<name>_force``, ``<name>_displacement``) and checkpoint keys."""

    name: str
    shape: ImpactorShape
    radius: float
    position: tuple[float, float, float]
    face: str = "top"
    motion: RigidMotion = RigidMotion.FREE
    axis: str = "y"
    mass: float = math.inf
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    displacement: tuple[float, float, float] | None = None
    amplitude: Amplitude = field(default_factory=lambda: Amplitude.constant(1.0))
    penalty: float | None = None
    friction: float = 0.0
    normal: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "shape", ImpactorShape(self.shape))  # frozen: set once, here
        object.__setattr__(self, "motion", RigidMotion(self.motion))
        if not (self.friction >= 0.0 and math.isfinite(self.friction)):
            raise ValueError(f"a friction coefficient is finite and >= 0 (got {self.friction})")
        if self.face not in ("top", "bottom", "all") or self.axis not in ("x", "y"):
            raise ValueError(
                "a rigid body touches the top face, the bottom face or all nodes; "
                "its axis is x or y"
            )
        if self.face == "all" and self.friction > 0.0:
            raise ValueError("friction on face 'all' is not supported yet (no tangential springs "
                             "on the extra nodes)")  # fmt: skip
        plane = self.shape == ImpactorShape.PLANE
        if plane != (self.normal is not None):
            raise ValueError("a plane (and only a plane) has a normal")
        if plane:
            n = np.asarray(self.normal, dtype=float)
            length = float(np.linalg.norm(n))
            if not (math.isfinite(length) and length > 0.0):
                raise ValueError(f"a plane's normal must be a nonzero vector (got {self.normal})")
            object.__setattr__(self, "normal", tuple(float(x) for x in n / length))
        elif not (self.radius > 0.0 and math.isfinite(self.radius)):
            raise ValueError(f"a sphere's or cylinder's radius must be > 0 mm (got {self.radius})")

    @property
    def direction(self) -> np.ndarray:
        """(3,) the unit vector its history columns take the force and the displacement along:
        z for a sphere or a cylinder, minus the normal for a plane (from the structure towards
        the plane: its force positive as the structure pushes it back, its travel into the
        structure negative)."""
        if self.normal is None:
            return np.array([0.0, 0.0, 1.0])
        return -np.asarray(self.normal, dtype=float)

    @property
    def path(self) -> tuple[float, float, float]:
        """The vector a PRESCRIBED body's path scales: its displacement (mm) or velocity
        (mm/s)."""
        return self.displacement if self.displacement is not None else self.velocity

    def path_scale(self, t: float) -> float:
        """The factor of ``path`` at time t (s): the time curve (a displacement) or its
        integral (a velocity)."""
        if self.displacement is not None:
            return self.amplitude(t)
        return self.amplitude.integral(t)

    def prescribed_centre(self, t: float) -> np.ndarray:
        """The centre (3,) mm at time t (s) of a PRESCRIBED body."""
        return np.asarray(self.position, dtype=float) + np.asarray(self.path) * self.path_scale(t)


@dataclass(frozen=True)
class Lever:
    """The loading lever of a mixed-mode bending (MMB) test, ASTM D6671 ([lever]): a rigid,
    massless bar hinged to the node line ``hinge`` (a face group such as "x1&top", the upper
    arm's end), resting on the [[rigid]] body ``saddle`` (motion "lever") at mid-span, and
    pushed at its load point, ``load_arm`` c (mm) beyond the saddle, by a prescribed z
    ``displacement`` (mm) x the time curve or ``velocity`` (mm/s) x its integral (one of the
    two, the other None). Hinge, saddle and load point lie on one line in this order; the
    half-span L (hinge to saddle) comes from the geometry (``model.lever``)."""

    saddle: str
    hinge: str
    load_arm: float
    displacement: float | None = None
    velocity: float | None = None
    amplitude: Amplitude = field(default_factory=lambda: Amplitude.constant(1.0))

    def __post_init__(self) -> None:
        if (self.displacement is None) == (self.velocity is None):
            raise ValueError("a lever's load point takes a displacement or a velocity")
        if not self.load_arm > 0.0:
            raise ValueError(f"a lever's load_arm must be > 0 mm (got {self.load_arm})")

    def load_point(self, t: float) -> float:
        """The load point's z displacement (mm) at time t (s)."""
        if self.displacement is not None:
            return self.displacement * self.amplitude(t)
        return self.velocity * self.amplitude.integral(t)


@dataclass(frozen=True)
class Impactor:
    """The impactor as the config gives it."""

    shape: ImpactorShape  # a cylinder has its axis along y
    radius: float  # mm
    mass: float  # tonne
    position: tuple[float, float, float]  # mm: centre of the sphere, a point of the axis
    velocity: tuple[float, float, float]  # mm/s at t = 0
    penalty: float | None = None  # N/mm per node; None: from the laminate (``model.contact``)
    friction: float = 0.0  # Coulomb coefficient (0: frictionless)

    def __post_init__(self) -> None:
        object.__setattr__(self, "shape", ImpactorShape(self.shape))  # frozen: set once, here

    def body(self) -> RigidBody:
        """The impactor as a free rigid body on the top face (a cylinder along y)."""
        return RigidBody(
            "impactor",
            self.shape,
            self.radius,
            self.position,
            "top",
            RigidMotion.FREE,
            "y",
            self.mass,
            self.velocity,
            penalty=self.penalty,
            friction=self.friction,
        )
