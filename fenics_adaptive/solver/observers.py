"""What the explicit solver tells the rest of a run: the ``Observer`` interface.

Units: N, mm, s, tonne (energies in mJ = N mm).

An observer subclasses ``Observer`` and overrides only the methods it needs; the others do
nothing. The solver calls every observer in the order given, on every rank (an observer that
writes files decides itself which rank writes). The history writer, the field output, the
progress printer and the checkpoint writer of ``runner.execute`` are observers; so can be a
user's own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the solver imports this module: no cycle at run time
    from fenics_adaptive.adaptivity.events import RefinementEvent
    from fenics_adaptive.solver.explicit import ExplicitSolver, HistoryRow, RunStats


class Observer:
    """No-op base of everything that watches a run of ``explicit.ExplicitSolver``."""

    def on_start(self, solver: ExplicitSolver) -> None:
        """The solver has set up (or restored) its state, before the first evaluation."""

    def on_history(self, row: HistoryRow) -> None:
        """A history row (every ``output_interval`` s and at the end time)."""

    def on_fields(self, t: float) -> None:
        """Field output is due at time t (s), every ``field_interval`` s when that is set."""

    def on_progress(self, t: float) -> None:
        """The run reached time t (s) (every 64 steps)."""

    def on_refinement(self, event: RefinementEvent, dt: float, where: str) -> None:
        """The structure was refined (``event``) and the solver reacted: the time step is now
        dt (s), limited by ``where``."""

    def on_checkpoint(self, solver: ExplicitSolver) -> None:
        """A checkpoint is due (every ``checkpoint_interval`` steps, after the last step when
        that is set, and when a stop was requested): ``solver.state()`` is what to store."""

    def on_finish(self, stats: RunStats) -> None:
        """The run reached its end time."""
