"""The kinds and states a config names, as enums (standard library only).

String kinds are ``enum.StrEnum``: a member equals its TOML string (``ModelKind.ESL == "esl"``),
formats as it, and ``", ".join(Kind)`` lists the allowed values for an error message, so a
config file and existing comparisons with strings keep working. The interface state is an
``enum.IntEnum`` whose values are what the int8 state arrays hold, so that the arrays and the
numba kernels stay plain integers.
"""

from __future__ import annotations

from enum import IntEnum, StrEnum


class InterfaceState(IntEnum):
    """State of one ply interface of one cell (the values of ``Structure.interface_state``):
    not refined, refined weakly (an extra node layer: displacement kink), or strongly (two node
    layers joined by a cohesive element: displacement jump)."""

    NONE = 0
    WEAK = 1
    STRONG = 2

    @property
    def label(self) -> str:
        """The state as the config and the messages name it: "none", "weak", "strong"."""
        return self.name.lower()


class ModelKind(StrEnum):
    """``[model] kind``: equivalent single layer, adaptive (refines through the thickness),
    layerwise (one cell layer per mesh layer from the start)."""

    ESL = "esl"
    ADAPTIVE = "adaptive"
    LAYERWISE = "layerwise"


class MassScaling(StrEnum):
    """``[solver] mass_scaling``: lumped masses alone, or the through-thickness modes slowed
    to a target step (``model.mass_scaling``)."""

    NONE = "none"
    SELECTIVE = "selective"


class Refinement(StrEnum):
    """A refinement as the config names it: ``[interfaces] initial`` ("none", "weak", "strong")
    and ``[[refinement]] kind`` ("weak", "strong")."""

    NONE = "none"
    WEAK = "weak"
    STRONG = "strong"

    @property
    def state(self) -> InterfaceState:
        """The interface state this refinement leaves."""
        return InterfaceState[self.name]


class Kinematics(StrEnum):
    """``[model] kinematics``: linearised strain, or total Lagrangian (large rotations)."""

    SMALL = "small"
    FINITE = "finite"


class ThicknessIntegration(StrEnum):
    """``[model] thickness_integration``: the laminate pre-integrated onto three points through
    the thickness (exact in bending, cost independent of the ply count), or Gauss points ply by
    ply (``points_per_ply``; what ply damage always uses)."""

    PREINTEGRATED = "preintegrated"
    PLIES = "plies"


class MixedModeLaw(StrEnum):
    """``[cohesive] law``: the mixed-mode criterion of the critical energy release rate,
    Benzeggagh-Kenane or the power law (``materials.cohesive``)."""

    BK = "bk"
    POWER = "power"


class MotionKind(StrEnum):
    """What a ``[[prescribed]]`` entry prescribes: a displacement (mm) or a velocity (mm/s)."""

    DISPLACEMENT = "displacement"
    VELOCITY = "velocity"


class Partition(StrEnum):
    """``[mesh] partition``: how MPI ranks share the cells: patches of equal cost (a cell
    refined from the start costs more: ``parallel.balance``) or of equal cells."""

    COST = "cost"
    CELLS = "cells"


class Profile(StrEnum):
    """``profile`` of a time ramp: C1 smoothstep or straight line."""

    SMOOTH = "smooth"
    LINEAR = "linear"


class ImpactorShape(StrEnum):
    """``[impactor]`` and ``[[rigid]] shape``: a sphere, or a cylinder (its axis along y for
    the impactor, along ``axis`` for a rigid body)."""

    SPHERE = "sphere"
    CYLINDER = "cylinder"


class RigidMotion(StrEnum):
    """``[[rigid]] motion``: held where it is, moved along a prescribed path, free (a mass
    with an initial velocity, moved by the contact forces), or carried by the ``[lever]`` (the
    saddle of a mixed-mode bending test)."""

    FIXED = "fixed"
    PRESCRIBED = "prescribed"
    FREE = "free"
    LEVER = "lever"


class IndicatorKind(StrEnum):
    """The refinement indicators of ``[indicators]`` (``adaptivity.indicators``): the ply
    failure index (weak), matrix damage and the interface stress criterion (strong), the
    delamination front (strong) and the weak-to-strong timer ``strong_after``."""

    PLY_FAILURE = "ply_failure"
    INTERFACE_STRESS = "interface_stress"
    MATRIX_DAMAGE = "matrix_damage"
    FRONT_DISTANCE = "front_distance"
    STRONG_AFTER = "strong_after"
