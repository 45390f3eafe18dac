"""The time loop's work arrays of one DOF block and the per-block arithmetic of a step.

Units: N, mm, s, tonne. A ``BlockState`` holds views of the block's owned DOFs (u, v, f) and
arrays allocated once per layout of the block, so that the loop allocates nothing; its
``accelerate`` and ``damped_velocity`` write into them; ``energies_at_step`` measures the
kinetic and damping energy at t_n the way the scheme sees them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fenics_adaptive.model.mass_scaling import SelectiveMass
from fenics_adaptive.model.structure import Block
from fenics_adaptive.parallel.reductions import dot


# ------------------------------------------------------------------ per-step kernels
# One call each for what a step does to every DOF of a block, instead of a dozen numpy calls:
# on a small model the calls, not the arithmetic, were the cost of a step.
@njit(cache=True)
def move_block(
    v,
    acc,
    mean_dt,
    dt,
    accelerate,
    du,
    u,
    fixed,
    u_next,
    f,
    f_old,
    f_ext,
    f_ext_old,
    reaction,
    reaction_old,
):
    """v += h a (if ``accelerate``), du = dt v, u += du, the prescribed DOFs on ``u_next``,
    and the forces of t_n kept as the old ones."""
    for i in range(len(u)):
        if accelerate:
            v[i] += acc[i] * mean_dt
        du[i] = v[i] * dt
        u[i] += du[i]
        f_old[i] = f[i]
        f_ext_old[i] = f_ext[i]
    for k in range(len(fixed)):
        u[fixed[k]] = u_next[k]
        reaction_old[k] = reaction[k]


@njit(cache=True)
def block_work(f_old, f, f_ext_old, f_ext, du, fixed, reaction_old, reaction):
    """(internal, external) work of the step just made (mJ): trapezoidal in the forces, the
    prescribed DOFs' reactions in the external work."""
    internal = 0.0
    external = 0.0
    for i in range(len(du)):
        internal += (f_old[i] + f[i]) * du[i]
        external += (f_ext_old[i] + f_ext[i]) * du[i]
    for k in range(len(fixed)):
        external += (reaction_old[k] + reaction[k]) * du[fixed[k]]
    return 0.5 * internal, 0.5 * external


@njit(cache=True, inline="always")
def _prescribed_acceleration(u_next, u_now, dt, mean_dt, v):
    """The acceleration that takes a prescribed DOF from u_now to u_next over the next step,
    ((u_next - u_now) / dt - v) / h: the one rule."""
    a = (u_next - u_now) / dt
    a -= v
    a /= mean_dt
    return a


@njit(cache=True)
def given_accelerations(fixed, u_next, u_now, dt, mean_dt, v, acc):
    """Each prescribed DOF's acceleration (``_prescribed_acceleration``) into ``acc``."""
    for k in range(len(fixed)):
        i = fixed[k]
        acc[i] = _prescribed_acceleration(u_next[k], u_now[k], dt, mean_dt, v[i])


@njit(cache=True)
def lumped_accelerations(f_ext, f, contact, inv_m, acc):
    """acc = (f_ext - f + contact) / m in one pass (``contact`` empty: none; ``inv_m``: 1 / m,
    0 where a DOF has no mass of its own)."""
    if len(contact):
        for i in range(len(acc)):
            acc[i] = (f_ext[i] - f[i] + contact[i]) * inv_m[i]
    else:
        for i in range(len(acc)):
            acc[i] = (f_ext[i] - f[i]) * inv_m[i]


@njit(cache=True)
def add_scaled(target, x, size):
    """target += size x, in place (no temporary)."""
    for i in range(len(target)):
        target[i] += size * x[i]


@njit(cache=True)
def prescribed_accelerations(
    fixed, u_next, u_now, dt, mean_dt, v, acc, m, f, f_ext, contact, reaction
):
    """On each prescribed DOF the acceleration that takes it to u(t_{n+1}) into ``acc``, and
    its reaction m a + f_int - f_ext - f_contact (``contact`` empty: none)."""
    for k in range(len(fixed)):
        i = fixed[k]
        a = _prescribed_acceleration(u_next[k], u_now[k], dt, mean_dt, v[i])
        acc[i] = a
        r = m[i] * a
        r += f[i]
        r -= f_ext[i]
        if len(contact):
            r -= contact[i]
        reaction[k] = r


# What a checkpoint keeps of each block: every array the next step reads (u and v with their
# ghosts; the rest owned), so that a resumed run repeats the uninterrupted one bit for bit.
BLOCK_ARRAYS = ("u_all", "v_all", "du", "f_old", "f_ext_old", "reaction_old")


class BlockState:
    """Work arrays of one block, allocated once per layout of the block.

    ``block``: the DOF block (``structure.Block``); ``damping``: the global mass-proportional
    damping (1/s); ``old``: the state of the block before it grew (a refinement), whose DOFs'
    history (``du``, ``f_old``, ``f_ext_old``, ``reaction_old``) is carried over;
    ``scaled_mass``: the block's selectively scaled mass (``model.mass_scaling``; None: the
    lumped masses alone), undamped."""

    def __init__(
        self,
        block: Block,
        damping: float,
        old: BlockState | None = None,
        scaled_mass: SelectiveMass | None = None,
    ):
        n = block.n_owned
        self.block = block
        self.scaled_mass = scaled_mass
        # DOFs on some rank (the same answer on every rank): a block empty everywhere (the
        # extra nodes of a model not yet refined) is skipped by the step, its scatters too
        index_map = block.u.index_map
        self.live = index_map.size_global > 0
        self.u = block.u.array[:n]
        self.v = block.v.array[:n]
        self.f = block.f.array[:n]
        self.m = block.mass
        # constrained DOFs (border extra nodes) have no mass of their own: they follow masters
        self.inv_m = np.divide(1.0, self.m, out=np.zeros(n), where=self.m > 0.0)
        self.acc, self.du, self.f_old, self.f_ext, self.f_ext_old = (np.zeros(n) for _ in range(5))
        self.damping = np.full(n, damping)
        self.damping[block.fixed] = 0.0
        self.shrink, self.grow, self.v_mid, self.v_next = (np.zeros(n) for _ in range(4))
        k = len(block.fixed)
        self.u_now, self.u_next = np.zeros(k), np.zeros(k)
        self.reaction, self.reaction_old = np.zeros(k), np.zeros(k)
        self.no_contact = np.zeros(0)
        if scaled_mass is not None:
            # all local DOFs: this rank's share of the residual and of the accelerations, the
            # latter summed on the owners in the forces' exchange (``share_accelerations``)
            self.f_all = block.f.array
            self.residual_share = np.zeros(len(self.f_all))
            self.shares = np.zeros(len(self.f_all))
        # forces added after that exchange (the MMB lever's hinge): the contributors, and the
        # accelerations and reaction shares of their shapes (``late_forces``)
        self.late: list = []
        self.late_accelerations, self.late_reactions = np.zeros((0, n)), np.zeros((0, k))
        if old is not None:  # the block grew: carry the old DOFs' history over
            n_old = len(old.du)
            for name in ("du", "f_old", "f_ext_old"):
                getattr(self, name)[:n_old] = getattr(old, name)
            _, new_at, old_at = np.intersect1d(
                block.fixed, old.block.fixed, assume_unique=True, return_indices=True
            )
            self.reaction_old[new_at] = old.reaction_old[old_at]

    def late_forces(self, contributors: list) -> None:
        """Collective (a scaled mass): the CONTACT ``contributors`` that add a force after the
        forces' exchange (``complete``), with the accelerations and reaction shares of their
        forces' shapes (``SelectiveMass.responses``), for ``accelerate`` to add."""
        n = self.block.n_owned
        shapes = np.zeros((len(contributors), n))  # (a rank may own no DOF)
        for row, contributor in enumerate(contributors):
            shapes[row] = contributor.late_force_shape(n)
        self.late = list(contributors)
        self.late_accelerations, self.late_reactions = self.scaled_mass.responses(shapes)

    def share_accelerations(
        self, contact_force: np.ndarray | None, dt: float, mean_dt: float
    ) -> np.ndarray:
        """A scaled mass, before the forces' exchange: this rank's share of the accelerations
        (``SelectiveMass.partial``) from its share of the residual, f_ext + f_contact - f_int
        (``f_int``: this rank's part of every local DOF, not yet summed), and the given
        accelerations of its prescribed DOFs; returns the array (all local DOFs) for the
        exchange to sum on the owners. Arguments as ``accelerate``'s."""
        n = self.block.n_owned
        np.negative(self.f_all, out=self.residual_share)
        owned = self.residual_share[:n]
        owned += self.f_ext
        if contact_force is not None:
            owned += contact_force
        if len(self.block.fixed):
            given_accelerations(
                self.block.fixed, self.u_next, self.u_now, dt, mean_dt, self.v, owned
            )
        self.scaled_mass.partial(self.residual_share, self.shares)
        return self.shares

    def accelerate(self, contact_force: np.ndarray | None, dt: float, mean_dt: float) -> None:
        """a = M^-1 (f_ext + f_contact - f_int) (``contact_force``: the CONTACT contributors'
        force on this block, N, if any; M: the lumped or the scaled mass); on the prescribed
        DOFs the acceleration that takes them exactly to u(t_{n+1}) and the reaction force it
        needs. ``dt``: dt_{n+1/2} (s); ``mean_dt``: (dt_{n-1/2} + dt_{n+1/2}) / 2 (s). With a
        scaled mass, after the forces' exchange summed the ``share_accelerations`` of the
        ranks, plus those of the forces added after it (``late_forces``)."""
        if self.scaled_mass is None:
            contact = self.no_contact if contact_force is None else contact_force
            lumped_accelerations(self.f_ext, self.f, contact, self.inv_m, self.acc)
        if len(self.block.fixed):
            self._prescribed_accelerations(contact_force, dt, mean_dt)
        if self.scaled_mass is not None:
            self.scaled_mass.finish(self.shares, self.acc, self.reaction)
            for row, contributor in enumerate(self.late):
                size = contributor.late_force_size
                add_scaled(self.acc, self.late_accelerations[row], size)
                add_scaled(self.reaction, self.late_reactions[row], size)

    def _prescribed_accelerations(
        self, contact_force: np.ndarray | None, dt: float, mean_dt: float
    ) -> None:
        """The prescribed DOFs' accelerations into ``acc`` and their reactions m a + f_int -
        f_ext - f_contact (lumped m; a scaled mass adds its share in ``SelectiveMass.finish``)."""
        prescribed_accelerations(
            self.block.fixed,
            self.u_next,
            self.u_now,
            dt,
            mean_dt,
            self.v,
            self.acc,
            self.m,
            self.f,
            self.f_ext,
            self.no_contact if contact_force is None else contact_force,
            self.reaction,
        )

    def next_velocity(self, mean_dt: float, out: np.ndarray) -> np.ndarray:
        """v_{n+1/2} = ((1 - c h/2) v_{n-1/2} + h a_n) / (1 + c h/2) into ``out`` (mm/s; may be
        ``v``): the one rule of the velocity update, with the implicit mass-proportional
        damping c. ``mean_dt``: h = (dt_{n-1/2} + dt_{n+1/2}) / 2 (s). Leaves ``v`` and
        ``acc`` as they are (unless ``out`` is ``v``)."""
        np.multiply(self.damping, 0.5 * mean_dt, out=self.shrink)
        np.add(self.shrink, 1.0, out=self.grow)
        np.subtract(1.0, self.shrink, out=self.shrink)
        self.shrink *= self.v
        np.multiply(self.acc, mean_dt, out=out)
        out += self.shrink
        out /= self.grow
        return out

    def damped_velocity(self, mean_dt: float) -> float:
        """v_{n-1/2} -> v_{n+1/2} with implicit mass-proportional damping (``mean_dt``: s);
        returns the energy the damping took over the update (mJ, this block on this rank):
        h c v_mid.M.v_mid with v_mid = (v_{n-1/2} + v_{n+1/2}) / 2."""
        self.v_mid[:] = self.v
        self.next_velocity(mean_dt, out=self.v)
        self.v_mid += self.v
        self.v_mid *= 0.5
        np.multiply(self.v_mid, self.v_mid, out=self.shrink)
        self.shrink *= self.m
        return mean_dt * dot(self.damping, self.shrink)

    def energies_at_step(self, mean_dt: float, dt: float) -> tuple[float, float]:
        """(kinetic energy, damping work of the update under way up to t_n) in mJ, this block on
        this rank, as the scheme itself measures them at t_n, so that the energy balance closes
        to round-off (``explicit``'s module docstring derives them). ``mean_dt``: h = (dt_{n-1/2}
        + dt_{n+1/2}) / 2, ``dt``: dt_{n+1/2} (s). With v- = v_{n-1/2}, v+ = v_{n+1/2} (from
        a_n, not yet taken), w = dt / h and v_mid = (v- + v+) / 2:

            kinetic = 1/2 v+.M.((1 - w) v+ + w v-)     (1/2 v+.M.v- at a constant step)
            damping = (c M v_mid).(h v_mid - dt/2 v+)

        Uses the block's scratch arrays; changes no state."""
        v_next = self.next_velocity(mean_dt, out=self.v_next)
        w = dt / mean_dt
        np.multiply(self.v, w, out=self.shrink)
        np.multiply(v_next, 1.0 - w, out=self.grow)
        self.shrink += self.grow
        if self.scaled_mass is None:
            np.multiply(self.m, v_next, out=self.grow)
        else:
            self.scaled_mass.multiply(v_next, self.grow)
        kinetic = 0.5 * dot(self.grow, self.shrink)
        np.add(self.v, v_next, out=self.v_mid)
        self.v_mid *= 0.5
        np.multiply(self.v_mid, mean_dt, out=self.shrink)
        np.multiply(v_next, 0.5 * dt, out=self.grow)
        self.shrink -= self.grow
        np.multiply(self.v_mid, self.m, out=self.grow)
        self.grow *= self.damping
        return kinetic, dot(self.grow, self.shrink)
