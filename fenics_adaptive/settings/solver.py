"""Solver and output settings as the config gives them (standard library only; the solver
that uses them is ``solver.explicit``).

Units: N, mm, s, tonne.
"""

from __future__ import annotations

from dataclasses import dataclass

from fenics_adaptive.settings.kinds import MassScaling


@dataclass(frozen=True)
class SolverSettings:
    """The time integration of a run: its end, the step (stable step x ``safety_factor``, or
    forced), damping, the output and checkpoint intervals and the run's guards."""

    end_time: float  # s
    output_interval: float  # s between history rows
    safety_factor: float = 0.9  # on the element-size stable step
    time_step: float | None = None  # forced step (s); must not exceed the stable one
    mass_damping: float = 0.0  # 1/s, on every free DOF
    field_interval: float | None = None  # s between field outputs (None: none)
    checkpoint_interval: int | None = None  # steps between checkpoints (None: none)
    # The run stops as failed when |energy balance| exceeds this share of the largest energy
    # of the run so far (guards.energy_error). Default: 12 x the worst share of every demo and
    # test case (1.6e-2, the TCB's adaptive run right after its refinement; most stay below
    # 5e-4), a fifth of an error as large as the energies themselves.
    energy_error_limit: float = 0.2
    max_steps: int = 10**9  # a run (and `check`) refuses to take more steps than this
    # "none": lumped masses; "selective": the through-thickness modes slowed to a target step
    # (model.mass_scaling), s: that target (None: the step the in-plane size allows)
    mass_scaling: MassScaling = MassScaling.NONE
    mass_scaling_step: float | None = None

    def __post_init__(self) -> None:
        if self.mass_scaling not in tuple(MassScaling):
            raise ValueError(
                f"mass_scaling must be one of {', '.join(MassScaling)}, got {self.mass_scaling!r}"
            )


@dataclass(frozen=True)
class Probe:
    """What the history reports: the mean displacement of a face and the reaction force on a
    (prescribed) face, both in one component, and the applied-load resultant in that
    component."""

    displacement_face: str
    reaction_face: str
    component: str
    displacement_x: tuple[float, float] | None = None  # only the face's nodes in this x range


@dataclass(frozen=True)
class FieldSelection:
    """What of the model the field files hold ([output] fields_plies, fields_box,
    ply_fields_every): the element, cohesive and ply files only the elements whose reference
    centroid lies in ``box`` (x_min, x_max, y_min, y_max, z_min, z_max; mm; None: all), the ply
    file only the plies ``plies`` (1-based; None: all), and only every ``ply_every``-th field
    output (the ply file is the largest: one hexahedron per ply per element)."""

    plies: tuple[int, ...] | None = None
    box: tuple[float, ...] | None = None
    ply_every: int = 1

    def __post_init__(self) -> None:
        if self.box is not None and len(self.box) != 6:
            raise ValueError(f"box needs 6 numbers (x_min, x_max, ...), got {len(self.box)}")
        if self.ply_every < 1:
            raise ValueError(f"ply_every must be at least 1 (got {self.ply_every})")
