"""Static equilibrium of a whole ``Structure``: ESL, adaptive (refined cells, extra nodes, the
border of a refined region) and layerwise, with its cohesive elements and rigid bodies.

Units: N, mm.

``static.solve_static`` knows only the UFL cells of the base model. This module solves

    R(u) = f_ext(t) + f_contact(u) - f_int(u) = 0

with the package's own force evaluation (``Structure.internal_force``, the rigid bodies'
``Contact.add_force``), so that a static answer and the explicit solver's quasi-static one
come from the same forces. The tangent is *probed*: with a distance-2 colouring of the nodes,
one force evaluation gives the columns of every node of one colour and one component at once
(no two of them share a neighbour, so each force entry comes from exactly one of them).

What is linear and what is not. Solids are linear (small strain; finite kinematics and ply
damage are for the caller to refuse or switch off). Cohesive elements are taken with their
initial stiffness (``CohesiveSet.linear_elastic``: no damage onset), so an intact interface is
a linear spring layer. Insert films (``[[delamination]]``) are unilateral: open faces carry
nothing, closed faces the law's compression branch (frictionless penalty contact). Rigid
bodies are unilateral penalty contacts too. The solution is therefore found by Newton's method
on a piecewise-linear residual (a semismooth Newton / active-set iteration):

- a linear structure converges in one step (the first tangent is probed about u = 0 with unit
  probes, exactly as a stiffness matrix is);
- with films, the first tangent is that of open films (``FILM_OPENING``): where the faces
  would then overlap, the next step closes them all at once; later steps probe about the
  current u with probes small against it (``PROBE``), so that the tangent of each face is
  that of its side of the kink; a film zone the iteration closed but the solution opens
  opens one element per step (``NEWTON_STEPS``);
- with rigid bodies, a structure may be held only by them (a beam on rollers): where its
  tangent is singular (no body touches yet), it gets a small spring on every free DOF
  (``REGULARISATION`` of the mean diagonal), which changes the path, not the solution (the
  residual is the true one; a spring on every step would make Newton converge only
  linearly); a Newton step
  moves no node farther than ``STEP_LIMIT`` of the thinnest of laminate and bodies, and the
  bodies travel to their end position in increments of at most that (a node pressed deeper
  into a body than that could be pushed out on its far side);
- an increment starts from the secant extrapolation of the last two solutions (the first
  from rest): a near-linear response starts close to its answer, with the nodes a body
  pushes already moved with it;
- if Newton does not settle on an increment, the increment is halved (``MAX_BISECTIONS``).

Border DOFs (extra nodes on the border of a refined region) follow their masters
(``Structure.follow_border``) and are no unknowns: their forces reach the masters through the
border's transfer inside ``internal_force``, so the probed tangent is T^T K T.

Serial only: the probing reads node neighbourhoods on one rank.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc

# probe size about a non-zero state, relative to the largest displacement (the tangent of a
# piecewise-linear force is exact for probes that stay on one side of every kink)
PROBE = 1e-10
# the first tangent of a structure with insert films: probed with the films open by this share
# of the thickness, with probes of FIRST_PROBE of it (open films are the better first guess: a
# first guess of bonded films leaves a zone closed ahead of the crack that the iteration opens
# one element per step)
FILM_OPENING = 1e-3
FIRST_PROBE = 1e-6
# the largest Newton step with rigid bodies, as a share of the thinnest of the laminate and the
# bodies' radii: a structure held only by bodies (the first step moves it freely) does not jump
# through them
STEP_LIMIT = 0.25
# Newton steps per increment, plus one per insert-film element: a zone of film faces that an
# iterate closes but the solution opens (faces touching without pressure: the ENF's arms have
# equal curvatures) carries its tension at its edge only, as a crack tip does, so each step
# opens one element more (about 60 steps on the 65-element film of demos/fracture_tests_enf)
NEWTON_STEPS = 40
# how often ``solve`` may halve its load increment before it gives up
MAX_BISECTIONS = 8
# spring added to the tangent's diagonal of the free DOFs when rigid bodies act, relative to
# the mean diagonal entry
REGULARISATION = 1e-6


def node_colouring(elements: Iterable[Sequence[int]], n_nodes: int) -> np.ndarray:
    """Greedy distance-2 colouring: nodes that share an element, or share a neighbour, get
    different colours (the condition for probing a stiffness matrix one colour at a time).
    ``elements``: the node lists of the elements (any length)."""
    neighbours: list[set[int]] = [set() for _ in range(n_nodes)]
    for row in elements:
        for a in row:
            neighbours[a].update(int(b) for b in row)
    colour = np.full(n_nodes, -1, dtype=np.int64)
    for node in range(n_nodes):
        taken = set()
        for b in neighbours[node]:
            taken.update(int(colour[c]) for c in neighbours[b])
        c = 0
        while c in taken:
            c += 1
        colour[node] = c
    return colour


@dataclass
class SparseMatrix:
    """A square matrix in coordinate form (enough for probing, checking and handing to PETSc)."""

    n: int
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return np.bincount(self.rows, weights=self.values * x[self.cols], minlength=self.n)

    def asymmetry(self) -> float:
        """max |K - K^T| / max |K| (entries missing from the pattern count as zero)."""
        keys = self.rows * self.n + self.cols
        order = np.argsort(keys)
        keys, values = keys[order], self.values[order]
        transposed = self.cols[order] * self.n + self.rows[order]
        at = np.minimum(np.searchsorted(keys, transposed), len(keys) - 1)
        partner = np.where(keys[at] == transposed, values[at], 0.0)
        return float(np.abs(values - partner).max() / np.abs(values).max())

    def diagonal(self) -> np.ndarray:
        return np.bincount(
            self.rows, weights=np.where(self.rows == self.cols, self.values, 0.0), minlength=self.n
        )

    def submatrix_petsc(self, keep: np.ndarray, shift: float = 0.0) -> PETSc.Mat:
        """PETSc AIJ matrix of the rows and columns ``keep`` (sorted indices), ``shift`` added
        to its diagonal, serial."""
        new = np.full(self.n, -1, dtype=np.int64)
        new[keep] = np.arange(len(keep))
        r, c = new[self.rows], new[self.cols]
        inside = (r >= 0) & (c >= 0)
        r, c, v = r[inside], c[inside], self.values[inside]
        if shift:
            index = np.arange(len(keep))
            r, c, v = (
                np.concatenate([r, index]),
                np.concatenate([c, index]),
                np.concatenate([v, np.full(len(keep), shift)]),
            )
        order = np.lexsort((c, r))
        r, c, v = r[order], c[order], v[order]
        # duplicates (the shift on an existing diagonal entry) summed
        key = r * len(keep) + c
        first = np.concatenate([[True], key[1:] != key[:-1]])
        v = np.add.reduceat(v, np.flatnonzero(first)) if len(v) else v
        r, c = r[first], c[first]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=len(keep)))])
        return PETSc.Mat().createAIJ(
            size=(len(keep), len(keep)),
            csr=(indptr.astype(PETSc.IntType), c.astype(PETSc.IntType), v),
            comm=PETSc.COMM_SELF,
        )


def solve_sparse(K: SparseMatrix, free: np.ndarray, rhs: np.ndarray, shift: float = 0.0):
    """x on the ``free`` DOFs of (K + shift I)[free, free] x = rhs (direct LU, serial)."""
    A = K.submatrix_petsc(free, shift)
    b = PETSc.Vec().createWithArray(np.ascontiguousarray(rhs), comm=PETSc.COMM_SELF)
    x = b.duplicate()
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.solve(b, x)
    reason = ksp.getConvergedReason()
    out = x.getArray().copy()
    for obj in (ksp, A, b, x):
        obj.destroy()
    if reason < 0 or not np.all(np.isfinite(out)):
        raise np.linalg.LinAlgError(
            "the static system is singular: a part of the model is not held (no support, "
            "prescribed motion or rigid body stops it moving as a rigid body)"
        )
    return out


class StaticSystem:
    """The static problem of ``structure`` at time t (s): loads and prescribed displacements at
    t, the rigid bodies ``contacts`` (``model.contact.Contact``, fixed or driven, at their
    position at t). Combined DOF numbering: base DOFs, then extra DOFs, 3 per node."""

    def __init__(self, structure, t: float, contacts: Sequence = ()):
        if structure.comm.size > 1:
            raise RuntimeError("static equilibrium: serial only (run it on one rank)")
        self.structure, self.t, self.contacts = structure, t, list(contacts)
        self.n_base_dofs = len(structure.base.u.x.array)
        self.n = self.n_base_dofs + len(structure.extra.vectors["u"].array)
        self.f_ext = np.zeros(self.n)
        structure.loads.external_force(
            t, self.f_ext[: self.n_base_dofs], self.f_ext[self.n_base_dofs :]
        )
        base, extra = structure.base_block, structure.extra_block
        self.fixed = np.concatenate([base.fixed, extra.fixed + self.n_base_dofs]).astype(np.int64)
        motions = np.concatenate([base.fixed_motion, extra.fixed_motion])
        self.fixed_motion = motions.astype(np.int64)
        self.fixed_values = np.array([structure.motions[m].displacement(t) for m in motions])
        self.slaves = np.asarray(structure.border.dofs, dtype=np.int64)
        self.free = np.setdiff1d(np.arange(self.n), np.concatenate([self.fixed, self.slaves]))
        self._contact_force = [np.zeros(self.n_base_dofs), np.zeros(self.n - self.n_base_dofs)]
        # the values at t, which ``scale`` takes a share of (the bodies' travel from their start)
        self._full = (self.f_ext.copy(), self.fixed_values.copy(),
                      [(c.origin.copy(), c.centre - c.origin) for c in self.contacts])  # fmt: skip
        self.factor = 1.0
        self.contact_norm = 0.0  # N: of the bodies' forces at the last resisting_force
        self._probing = None  # ``_pattern``, made at the first tangent
        # mm: the largest Newton step when rigid bodies act (a share of the thinnest of the
        # laminate and the bodies)
        # (a plane has no radius)
        radii = [c.body.radius for c in self.contacts if c.body.radius > 0.0]
        sizes = [structure.laminate.thickness, *radii]
        self.step_limit = STEP_LIMIT * min(sizes)

    def largest_travel(self) -> float:
        """mm: how far the farthest-moving body goes from its start to its position at t."""
        return max((float(np.linalg.norm(travel)) for _, travel in self._full[2]), default=0.0)

    def scale(self, factor: float) -> None:
        """Loads, prescribed displacements and the bodies' travel at ``factor`` (0 .. 1) of
        their values at t: a step of the continuation ``solve`` falls back on."""
        f_ext, fixed_values, travels = self._full
        np.multiply(f_ext, factor, out=self.f_ext)
        np.multiply(fixed_values, factor, out=self.fixed_values)
        for contact, (origin, travel) in zip(self.contacts, travels, strict=True):
            contact.centre[:] = origin + factor * travel
        self.factor = factor

    # ---------------------------------------------------------------- forces
    def set_displacement(self, u: np.ndarray) -> None:
        """Put u (combined) into the structure; the border DOFs follow their masters."""
        structure = self.structure
        structure.base.u.x.array[:] = u[: self.n_base_dofs]
        structure.extra.vectors["u"].array[:] = u[self.n_base_dofs :]
        structure.follow_border()

    def displacement(self) -> np.ndarray:
        """The structure's displacement, combined (border DOFs where their masters put them)."""
        s = self.structure
        return np.concatenate([s.base.u.x.array, s.extra.vectors["u"].array])

    def contact_force(self) -> np.ndarray:
        """The rigid bodies' forces on the nodes (N, combined) at the structure's displacement."""
        out = np.zeros(self.n)
        for contact in self.contacts:
            for part in self._contact_force:
                part.fill(0.0)
            contact.add_force(self.t, *self._contact_force)
            out[: self.n_base_dofs] += self._contact_force[0]
            out[self.n_base_dofs :] += self._contact_force[1]  # (a body on every node)
        return out

    def resisting_force(self, u: np.ndarray) -> np.ndarray:
        """f_int(u) - f_contact(u) (N, combined; zero on border DOFs, their share moved to the
        masters)."""
        self.set_displacement(u)
        structure = self.structure
        structure.internal_force(self.t)
        f = np.concatenate([structure.f_base.array, structure.f_extra.array])
        if self.contacts:
            contact = self.contact_force()
            f -= contact
            self.contact_norm = float(np.linalg.norm(contact))
        return f

    # ---------------------------------------------------------------- tangent
    def elements(self) -> list[np.ndarray]:
        """Node lists coupling the unknowns: the solid elements, the cohesive elements, a
        rigid body's nodes alone (their forces depend on their own motion only), with each
        border node replaced by its masters."""
        structure = self.structure
        rows = [*structure.elements()[0], *structure.cohesive.nodes]
        if len(self.slaves):
            border = structure.border
            masters: dict[int, set[int]] = {}
            for dof, pair in zip(border.dofs, border.masters, strict=True):
                masters.setdefault(int(dof) // 3, set()).update(int(m) // 3 for m in pair)
            rows = [
                np.array(sorted({m for a in row for m in masters.get(int(a), (int(a),))}))
                if any(int(a) in masters for a in row)
                else row
                for row in rows
            ]
        return rows

    def _pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(node colours, the node pairs (i, j) that share an element, which DOFs are
        unknowns): what the probing needs of the structure's connectivity, which a static
        solve does not change; made at the first tangent, kept for the others."""
        if self._probing is None:
            elements = self.elements()
            pairs = _node_pairs(elements)
            unknown = np.ones(self.n, dtype=bool)
            unknown[self.slaves] = False
            colour = node_colouring(elements, self.n // 3)
            self._probing = (colour, pairs[:, 0], pairs[:, 1], unknown)
        return self._probing

    def tangent(self, u: np.ndarray, f_u: np.ndarray, probe: float) -> tuple[SparseMatrix, int]:
        """d(f_int - f_contact)/du at u (f_u: its value there) by probes of size ``probe``
        (mm); returns (K over all combined DOFs, force evaluations). Rows and columns of
        border DOFs are left empty."""
        n_nodes = self.n // 3
        colour, i_node, j_node, unknown = self._pattern()
        rows, cols, values = [], [], []
        evaluations = 0
        for c in range(int(colour.max()) + 1 if n_nodes else 0):
            in_colour = colour[j_node] == c
            i_c, j_c = i_node[in_colour], j_node[in_colour]
            for d in range(3):
                moved = 3 * np.flatnonzero(colour == c) + d
                moved = moved[unknown[moved]]
                if not len(moved):
                    continue
                trial = u.copy()
                trial[moved] += probe
                column = (self.resisting_force(trial) - f_u) / probe
                evaluations += 1
                keep = unknown[3 * j_c + d]
                for a in range(3):
                    rows.append(3 * i_c[keep] + a)
                    cols.append(3 * j_c[keep] + d)
                    values.append(column[3 * i_c[keep] + a])
        self.set_displacement(u)
        K = SparseMatrix(
            self.n,
            np.concatenate(rows) if rows else np.zeros(0, np.int64),
            np.concatenate(cols) if cols else np.zeros(0, np.int64),
            np.concatenate(values) if values else np.zeros(0),
        )
        return K, evaluations


def _node_pairs(elements: Sequence[np.ndarray]) -> np.ndarray:
    """(i, j) for every two nodes sharing an element (both orders, each pair once)."""
    by_length: dict[int, list[np.ndarray]] = {}
    for row in elements:
        by_length.setdefault(len(row), []).append(np.asarray(row, dtype=np.int64))
    pairs = [np.zeros((0, 2), np.int64)]
    for length, rows in by_length.items():
        nodes = np.array(rows)
        pairs.append(
            np.stack(
                [np.repeat(nodes, length, axis=1).ravel(), np.tile(nodes, (1, length)).ravel()],
                axis=1,
            )
        )
    return np.unique(np.concatenate(pairs), axis=0)


@dataclass
class Equilibrium:
    """A solution of ``solve``: the displacement (combined DOFs, mm, left in the structure too),
    the last tangent, how the iteration went."""

    u: np.ndarray
    tangent: SparseMatrix
    iterations: int
    force_evaluations: int
    residual: float  # |R(u)| on the free DOFs / the forces that load the body
    resisting_force: np.ndarray  # N, f_int - f_contact at u (combined)


def _films_opened(system: StaticSystem) -> np.ndarray:
    """A displacement (combined) that opens every insert film by ``FILM_OPENING`` of the
    laminate's thickness (its upper faces lifted along z): the tangent about it is that of
    open films, the first guess of the iteration."""
    structure = system.structure
    cohesive = structure.cohesive
    upper = np.unique(cohesive.nodes[cohesive.inserted(), 4:])
    offset = np.zeros(system.n)
    offset[3 * upper + 2] = FILM_OPENING * structure.laminate.thickness
    return offset


def solve(
    system: StaticSystem, tolerance: float = 1e-9, max_iterations: int | None = None
) -> Equilibrium:
    """The equilibrium at the system's full loads (see the module docstring): Newton's method
    at once; if that does not converge (a body pressed far into a face, contact states that
    keep switching), by continuation: the loads, motions and bodies' travel in increments
    (halved until Newton converges on each, up to ``MAX_BISECTIONS`` times), each increment
    starting from the secant extrapolation of the last two solutions. ``max_iterations``
    (Newton steps per increment): by default ``NEWTON_STEPS`` plus one per insert-film
    element. Raises RuntimeError if even the smallest increment does not converge,
    numpy.linalg.LinAlgError if the structure is not held."""
    if max_iterations is None:
        max_iterations = NEWTON_STEPS + int(system.structure.cohesive.inserted().sum())
    # bodies move at most a Newton step per increment: a node pressed deeper into a body than
    # the step limit could be pushed out on the wrong side
    travel = system.largest_travel()
    done, step, bisections = 0.0, min(1.0, system.step_limit / max(travel, 1e-300)), 0
    u, total, solution = None, 0, None
    # the solution before the last (its load factor, u): at rest before the first increment
    earlier = (0.0, np.zeros(system.n))
    while done < 1.0:
        target = min(1.0, done + step)
        system.scale(target)
        start = u
        if u is not None:  # secant predictor: a near-linear response starts near its answer
            start = u + (target - done) / (done - earlier[0]) * (u - earlier[1])
        try:
            solution = _newton(system, start, tolerance, max_iterations)
        except RuntimeError as error:
            bisections += 1
            if bisections > MAX_BISECTIONS:
                raise RuntimeError(
                    f"{error} (also in increments of {step:.3g} of the load)"
                ) from None
            step *= 0.5
            system.scale(done)
            if u is not None:
                system.set_displacement(u)
            continue
        total += solution.force_evaluations
        if u is not None:
            earlier = (done, u)
        u, done = solution.u, target
    solution.force_evaluations = total
    return solution


def _newton(system: StaticSystem, start: np.ndarray | None, tolerance: float,
            max_iterations: int) -> Equilibrium:  # fmt: skip
    """Newton's method on R(u) = f_ext + f_contact - f_int with probed tangents from ``start``
    (None: from rest, the first tangent with the insert films open). Raises RuntimeError if
    |R| does not fall below ``tolerance`` times the load scale in ``max_iterations`` steps."""
    structure = system.structure
    cohesive = structure.cohesive
    films = bool(len(cohesive)) and bool(cohesive.insert.any())
    # the cohesive elements' frame follows the deformed mid-surface: iterate with them too
    iterate = films or bool(system.contacts) or bool(len(cohesive))
    if start is None:
        u = np.zeros(system.n)
    else:
        u = start.copy()
    u[system.fixed] = system.fixed_values
    evaluations = 0
    residual = np.inf
    with cohesive.linear_elastic():
        f_u = system.resisting_force(u)
        u = system.displacement()  # the border DOFs where the masters put them
        for iteration in range(max_iterations + 1):
            r = system.f_ext - f_u
            # the forces that load the body: loads, reactions, the bodies' pressure
            scale = max(
                np.linalg.norm(system.f_ext[system.free]),
                np.linalg.norm(r[system.fixed]),
                system.contact_norm,
                1e-300,
            )
            residual = float(np.linalg.norm(r[system.free]) / scale)
            if iteration > 0 and (residual <= tolerance or not iterate):
                break
            if iteration == max_iterations or not np.isfinite(residual):
                raise RuntimeError(
                    f"static equilibrium: no convergence in {max_iterations} Newton steps "
                    f"(relative residual {residual:.3g}): the contacts or insert films keep "
                    "changing state"
                )
            if iteration == 0 and films and start is None:
                about = u + _films_opened(system)
                probe = FIRST_PROBE * structure.laminate.thickness
                K, n = system.tangent(about, system.resisting_force(about), probe)
                n += 1
            else:
                # from rest: unit probes (exact for the linear parts); later about u, small
                size = float(np.abs(u).max()) if iteration or start is not None else 0.0
                probe = PROBE * size if size > 0.0 else 1.0
                K, n = system.tangent(u, f_u, probe)
            evaluations += n + 1
            try:
                step = solve_sparse(K, system.free, r[system.free])
            except np.linalg.LinAlgError:
                if not system.contacts:
                    raise
                # held only by bodies it does not touch yet
                shift = REGULARISATION * float(np.abs(K.diagonal()[system.free]).mean())
                step = solve_sparse(K, system.free, r[system.free], shift)
            if system.contacts:  # never through a body: a node deep in it is pushed out behind
                step *= min(1.0, system.step_limit / max(float(np.abs(step).max()), 1e-300))
            u[system.free] += step
            f_u = system.resisting_force(u)
            u = system.displacement()
    return Equilibrium(u, K, iteration, evaluations, residual, f_u)
