"""Rigid bodies in penalty contact with the top or bottom face, or with every node, with Coulomb
friction if asked: an impactor, the rollers and noses of a bending or fracture test, the platen
of a crush test (``settings.loads.RigidBody``).

A body is a sphere of radius R about its centre c, a cylinder of radius R whose axis runs
along x or y through c, or a plane through c with the unit normal n (pointing to the
structure). Each node of its face (base nodes: refinement never moves the top and bottom
faces) at x = X + u gets the penalty force

    g = dist(x, body) - R,   f = k <-g> n,   n = unit vector from the centre (axis) to x,

(a plane: g = (x - c) . n, its own n) and the body gets -sum f. Without friction the contact
is conservative: the penalty springs store 1/2 k g^2. A body on face "all" (a platen on the
edge of a plate, the end of a tube) touches every owned base node, and the extra nodes of
refined cells that are free (a node bound to the border of a refined region follows its
masters, which the body touches), found again after each refinement. There k is the penalty
of a face node of an unrefined column, and each node's spring is k m / m_face, m its lumped
mass: the springs of a column add up to the same stiffness however it is split (ESL, refined,
layerwise), as its masses do, every node has the same contact frequency, and a refinement
moves springs between the nodes of a column as it moves mass. The springs' stiffness, not
their force: where the penetration varies through the thickness (a tilted plate), splitting a
column changes its contact force and the springs' energy at once; that change is booked as
refinement energy (``refinement_energy`` of the history), so that the energy balance stays
closed. Its default penalty takes the stiffest modulus (an edge is pressed along the plies)
and is capped for the in-plane step of the mesh, the same in every model. Friction is not
offered there (the extra nodes have no tangential springs), and its forces are no face
tractions to the indicators (``ExplicitSolver.face_force``: an end or an edge is pressed).
Erosion releases its extra nodes as it does the base nodes.

Friction (``friction`` = mu > 0; ``add_friction_forces``): Coulomb's law with a regularised
stick, as penalty codes do (LS-DYNA's contacts, Abaqus/Explicit's penalty friction): a node in
contact carries a tangential force t that grows with its slide relative to the body through a
tangential spring of the normal penalty k (stick, an elastic slip of at most mu f_n / k) until
|t| = mu f_n (slip). The body moves in translation only: its surface slides with its centre. The
energy friction dissipates is the work of the tangential forces on the slide, trapezoidal as
the solver's work, less the change of the energy in the tangential springs; it is booked in the
history (``<name>_friction_energy``) and taken off ``impact_work``, the work the contact does on
the structure, so that the run's energy balance still closes. Friction makes the contact path
dependent: the static solve leaves it out (``static_runner``).

How the body moves: FIXED stays at its centre; PRESCRIBED follows its path c(t); FREE is a mass
M in translation integrated by the same central-difference scheme as the structure (velocity
at half steps). The energy a body gives the structure (``impact_work``) is, for a free body,
its kinetic plus penalty energy at t = 0 minus now; for a driven one, the work its drive did,
sum of 1/2 (F_n + F_n+1) . (c_n+1 - c_n) with F = -(force of the structure on it), minus the
change of the penalty energy; with friction, less what friction dissipated. Either way it is
the work of the contact forces on the structure, so the energy balance of a run closes to the
scheme's O(dt^2) error.

As a force contributor (``model.forces``, kind CONTACT) a body adds its forces on its face's
DOFs, moves itself (``advance``), reports into the history (the [impactor]: ``contact_force``,
``impactor_displacement``; a [[rigid]] body: ``<name>_force`` and ``<name>_displacement``, z
components, a plane's along minus its normal; a body with friction
``<name>_friction_energy``; every body adds to ``impact_work``) and keeps its state for
checkpoints.

Ranks: a body's force and penalty energy are sums over the ranks' face nodes. A free body
(whose motion needs its force) and the lever's saddle (whose force the lever passes on to the
hinge) sum them every step; a fixed or prescribed body keeps this rank's share, its drive's
work too (both are additive over the ranks), and sums them when a history row is written: no
collective in the steps between. The sum of a free body is a nonblocking reduction started
with its force (``add_force``, before the internal forces) and completed in the wait of the
internal forces' reverse exchange (``pending_request``), so it costs the step no
synchronisation of its own. Whatever reads the sum first completes it (``finish``).

Penalty k (N/mm per node): by default the through-thickness stiffness of the laminate over one
node's area, max C33 * A_node / h, capped so that a node on its spring stays well inside the
stable step: k <= 0.05 m_node (2 / dt)^2. Contact is checked on the owned face nodes only, so
every node counts once on one rank.

Units: N, mm, s, tonne.
"""

from __future__ import annotations

import math

import numpy as np
from dolfinx import la
from mpi4py import MPI
from numba import njit

from fenics_adaptive.element.geometry import quad_areas
from fenics_adaptive.errors import InputError
from fenics_adaptive.model.forces import Contributor, ForceKind
from fenics_adaptive.model.loading import face_facets, face_nodes
from fenics_adaptive.parallel.redistribute import PARTIAL, REPLICATED, Rows
from fenics_adaptive.parallel.reductions import summed
from fenics_adaptive.settings.kinds import ImpactorShape, RigidMotion
from fenics_adaptive.settings.loads import Impactor, RigidBody

PLANE_AXIS = -2  # ``axis`` of a plane in the kernels (a sphere: -1; a cylinder: 0 or 1)


@njit(cache=True, inline="always")
def _offset(u, k, X, i, centre, axis, radius, normal):
    """(dx, dy, dz, distance, gap): the vector from the body's centre (a sphere, ``axis`` -1)
    or axis (a cylinder along x, 0, or y, 1) to the node at X[i] + u[k : k + 3], its length
    and the gap (mm, < 0 in contact) distance - radius; for a plane (``PLANE_AXIS``) its unit
    ``normal``, length 1 and the signed distance from the plane. The one geometry of the
    contact, for its normal and its friction alike: (dx, dy, dz) / distance is the normal."""
    if axis == PLANE_AXIS:
        gap = (
            (X[i, 0] + u[k] - centre[0]) * normal[0]
            + (X[i, 1] + u[k + 1] - centre[1]) * normal[1]
            + (X[i, 2] + u[k + 2] - centre[2]) * normal[2]
        )
        return normal[0], normal[1], normal[2], 1.0, gap
    dx = 0.0 if axis == 0 else X[i, 0] + u[k] - centre[0]
    dy = 0.0 if axis == 1 else X[i, 1] + u[k + 1] - centre[1]
    dz = X[i, 2] + u[k + 2] - centre[2]
    distance = np.sqrt(dx * dx + dy * dy + dz * dz)
    return dx, dy, dz, distance, distance - radius


@njit(cache=True)
def add_penalty_forces(
    u, nodes, active, X, centre, radius, axis, normal, penalty, weights, f, total
):
    """Add the contact forces on the face nodes ``nodes`` (reference positions X (n, 3), mm;
    displacements in the flat u, x y z interleaved) into the flat f (N) and put their
    reaction on the body into total (3,); returns the penalty energy (mJ). ``active`` (n,)
    bool: the nodes that can touch (False: erosion has removed every element holding it).
    ``axis``: -1 for a sphere, 0 or 1 for a cylinder along x or y, ``PLANE_AXIS`` for a plane
    of unit ``normal`` (3,) (read for a plane only). Node i's spring is ``penalty`` (N/mm)
    times ``weights[i]`` (1 on a face; on every node, its share of a column's mass). One
    pass: gather, penalty, scatter."""
    total[:] = 0.0
    energy = 0.0
    for i in range(nodes.shape[0]):
        if not active[i]:
            continue
        k = 3 * nodes[i]
        dx, dy, dz, distance, gap = _offset(u, k, X, i, centre, axis, radius, normal)
        if gap >= 0.0 or distance == 0.0:
            continue
        stiffness = penalty * weights[i]
        magnitude = -stiffness * gap / distance
        f[k] += magnitude * dx
        f[k + 1] += magnitude * dy
        f[k + 2] += magnitude * dz
        total[0] -= magnitude * dx
        total[1] -= magnitude * dy
        total[2] -= magnitude * dz
        energy += 0.5 * stiffness * gap * gap
    return energy


@njit(cache=True)
def add_friction_forces(
    u,
    nodes,
    active,
    X,
    centre,
    moved,
    radius,
    axis,
    normal,
    penalty,
    friction,
    previous,
    traction,
    f,
    total,
):
    """Add Coulomb friction with a regularised stick (``friction``: the coefficient mu) on the
    face nodes ``nodes`` (those ``active``, as in ``add_penalty_forces``) into the flat f (N)
    and its reaction into the body's ``total`` (3,). Each node in contact carries a tangential
    force t (``traction`` (n, 3), N: its state), held by a tangential spring of the normal
    ``penalty`` (N/mm) until it reaches mu f_n:

        t_trial = t_old (turned into the tangent plane, its size kept) - penalty * dv_t,
        t = t_trial                           if |t_trial| <= mu f_n (stick),
        t = mu f_n t_trial / |t_trial|        otherwise (slip),

    dv_t the tangential part of the node's displacement relative to the body since the last
    call (``previous`` (n, 3): the nodes' positions then, mm, updated here; ``moved`` (3,):
    the body's displacement since then, mm). A node out of contact carries none. Returns (the
    energy in the tangential springs, mJ; the energy friction dissipated since the last call,
    mJ: the work of the tangential forces on the relative motion, trapezoidal as the solver's,
    less the springs' change), so that the energy balance closes."""
    springs = 0.0
    dissipated = 0.0
    for i in range(nodes.shape[0]):
        k = 3 * nodes[i]
        dx, dy, dz, distance, gap = _offset(u, k, X, i, centre, axis, radius, normal)
        # the node's slide relative to the body since the last call (scalars: no allocation)
        x, y, z = X[i, 0] + u[k], X[i, 1] + u[k + 1], X[i, 2] + u[k + 2]
        sx = x - previous[i, 0] - moved[0]
        sy = y - previous[i, 1] - moved[1]
        sz = z - previous[i, 2] - moved[2]
        previous[i, 0], previous[i, 1], previous[i, 2] = x, y, z
        ox, oy, oz = traction[i, 0], traction[i, 1], traction[i, 2]
        tx, ty, tz = 0.0, 0.0, 0.0
        if gap < 0.0 and distance > 0.0 and active[i]:
            nx, ny, nz = dx / distance, dy / distance, dz / distance
            # the old force turned into the current tangent plane, its size kept
            on = ox * nx + oy * ny + oz * nz
            cx, cy, cz = ox - on * nx, oy - on * ny, oz - on * nz
            carried = np.sqrt(cx * cx + cy * cy + cz * cz)
            if carried > 0.0:
                keep = np.sqrt(ox * ox + oy * oy + oz * oz) / carried
                cx, cy, cz = cx * keep, cy * keep, cz * keep
            sn = sx * nx + sy * ny + sz * nz
            tx = cx - penalty * (sx - sn * nx)
            ty = cy - penalty * (sy - sn * ny)
            tz = cz - penalty * (sz - sn * nz)
            limit = friction * (-penalty * gap)
            size = np.sqrt(tx * tx + ty * ty + tz * tz)
            if size > limit:
                scale = limit / size
                tx, ty, tz = tx * scale, ty * scale, tz * scale
        traction[i, 0], traction[i, 1], traction[i, 2] = tx, ty, tz
        f[k] += tx
        f[k + 1] += ty
        f[k + 2] += tz
        total[0] -= tx
        total[1] -= ty
        total[2] -= tz
        stored = 0.5 * (tx * tx + ty * ty + tz * tz) / penalty
        before = 0.5 * (ox * ox + oy * oy + oz * oz) / penalty
        work = 0.5 * ((ox + tx) * sx + (oy + ty) * sy + (oz + tz) * sz)
        springs += stored
        dissipated += -work - (stored - before)
    return springs, dissipated


def _as_body(body: RigidBody | Impactor) -> RigidBody:
    """The rigid body of an [impactor] (a free body on the top face), or ``body`` itself."""
    return body.body() if isinstance(body, Impactor) else body


class Contact(Contributor):
    """A rigid body's state and its contact with the nodes of one face of a structure.

    ``body``: the body (an ``Impactor`` is taken as its free body on the top face);
    ``nodes``: owned face base nodes; ``mass_of_node``: their lumped masses (for the penalty
    cap); ``X``: their reference positions; ``area``: the in-plane area of a node (mm^2);
    ``C33``, ``h``: the stiffest through-thickness modulus (MPa) and the thickness (mm) (for
    the default penalty); ``displacement``: the base displacement vector (a DOLFINx vector,
    owned + ghost entries) the contact reads. ``Contact.on(body, structure)`` fills these in."""

    kind = ForceKind.CONTACT

    @classmethod
    def on(cls, body: RigidBody | Impactor, structure) -> Contact:
        body = _as_body(body)
        base = structure.base
        n_owned = base.V.dofmap.index_map.size_local
        every = body.face == "all"
        if every:  # every owned base node (both faces, and a layerwise mesh's inner layers)
            owned = np.arange(n_owned, dtype=np.int64)
        else:
            nodes = face_nodes(base, body.face)  # collective
            owned = nodes[nodes < n_owned]
        X = structure.X_base[owned]
        # the mean area of the face's facets over all ranks: one penalty for the whole face,
        # as in serial (of the face it touches: a curved shell's layers differ in area; on
        # every node, the mean of the two faces', a curved shell's mid-surface)
        faces = ("top", "bottom") if every else (body.face,)
        local = np.zeros(2 * len(faces))
        shortest = np.inf  # mm: the shortest edge of the faces' facets (face "all")
        for k, face in enumerate(faces):
            _, _, facets = face_facets(base, face)
            local[2 * k : 2 * k + 2] = quad_areas(facets).sum(), len(facets)
            if every and len(facets):  # (tensor order: edges 0-1, 2-3, 0-2, 1-3)
                edges = facets[:, [1, 3, 2, 3]] - facets[:, [0, 2, 0, 1]]
                shortest = min(shortest, float(np.linalg.norm(edges, axis=2).min()))
        sums = structure.comm.allreduce(local, op=MPI.SUM)
        area = float(np.mean(sums[0::2] / sums[1::2]))
        plies = structure.laminate.plies
        h = structure.laminate.thickness
        mass = structure.mass_base.array[3 * owned]
        if every:
            # a platen may press on an edge, along the fibres: the stiffest modulus; each
            # node's spring in proportion to its mass (``follow_refinement``), so that every
            # node has the frequency of a face node of an unrefined column of mass 2 m_face
            modulus = max(float(np.max(np.diag(p.material.stiffness())[:3])) for p in plies)
            face_mass = 0.5 * area * sum(p.material.rho * p.thickness for p in plies)
            mass = np.full(len(owned), face_mass)
            speed = max(math.sqrt(np.max(np.diag(p.material.stiffness())[:3]) / p.material.rho)
                        for p in plies)  # fmt: skip
            plane_step = structure.comm.allreduce(shortest, op=MPI.MIN) / speed
        else:
            modulus = max(p.material.stiffness()[2, 2] for p in plies)
        contact = cls(body, structure.comm, owned, X, mass, area, modulus, h, structure.base.u.x)
        if every:
            contact.structure = structure
            contact.face_mass = face_mass
            contact.plane_step = plane_step
        if structure.erosion:
            contact.watch_erosion(structure)
        return contact

    def __init__(
        self,
        body: RigidBody | Impactor,
        comm: MPI.Comm,
        nodes,
        X,
        mass_of_node,
        area,
        C33,
        h,
        displacement=None,
    ):
        body = _as_body(body)
        self.body = body
        self.name = body.name if body.name == "impactor" else f"rigid_{body.name}"
        self.key = "impactor" if body.name == "impactor" else f"rigid.{body.name}"
        self.free = body.motion == RigidMotion.FREE
        self.displacement = displacement
        self.comm = comm
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.X = np.ascontiguousarray(X)
        self.node_mass_min = comm.allreduce(
            float(mass_of_node.min()) if len(mass_of_node) else np.inf, op=MPI.MIN
        )
        self.natural_penalty = C33 * area / h
        self.penalty = body.penalty if body.penalty is not None else self.natural_penalty
        self.centre = np.array(body.position, dtype=float)
        self.origin = self.centre.copy()  # mm: the centre at t = 0
        self.path = np.array(body.path, dtype=float)  # a prescribed body's (mm or mm/s)
        # v_{n-1/2} of a free body; a driven body's is its path's
        self.velocity = np.array(body.velocity if self.free else (0.0, 0.0, 0.0), dtype=float)
        self.acceleration = np.zeros(3)
        self.t = 0.0  # s: the time of ``centre``
        self.last_dt = 0.0  # s: dt_{n-1/2}, of the last advance (0 before the first)
        self.initial = 0.0  # mJ: a free body's kinetic + penalty energy at t = 0
        self.initial_penalty = 0.0  # mJ: a driven body's penalty energy at t = 0
        self.drive_work = 0.0  # mJ: work of a driven body's drive so far
        self.previous_centre = self.centre.copy()  # at the last add_force
        self.previous_force = np.zeros(3)
        self.moved = np.zeros(3)  # mm: c_n+1 - c_n at the last add_force
        # whether add_force sums the force over the ranks every step (else on output steps:
        # the module docstring); the lever sets it for its saddle
        self.every_step = self.free
        self.force = np.zeros(3)  # on the body, N: over all ranks if every_step, else this rank's
        self.energy_penalty = 0.0  # mJ: likewise
        # force on the body, penalty energy (normal and tangential springs), friction's
        # dissipation so far (the step's work array, summed over the ranks as one)
        self.totals = np.zeros(5)
        # Coulomb friction (``add_friction_forces``): the coefficient, each face node's
        # tangential force (N) and position at the last evaluation (mm), the body's centre
        # then, and the energy friction dissipated on this rank so far (mJ)
        self.friction = body.friction
        self.traction = np.zeros((len(self.nodes), 3))
        self.previous = np.zeros((len(self.nodes), 3))
        self.friction_centre = self.centre.copy()
        self.slid = np.zeros(3)  # mm: the body's move since the last evaluation
        self.friction_started = False
        self.friction_local = 0.0
        self.friction_energy = 0.0  # mJ: over all ranks if every_step, else this rank's
        self._request = MPI.REQUEST_NULL  # the reduction of ``totals`` under way, if any
        self._taken = True  # ``totals`` of the last add_force are in force, energy, acceleration
        if body.shape == ImpactorShape.PLANE:
            self.axis = PLANE_AXIS
        else:
            self.axis = -1 if body.shape == ImpactorShape.SPHERE else "xy".index(body.axis)
        self.normal = np.array(body.normal if body.normal is not None else (0.0, 0.0, 0.0))
        self.direction = body.direction  # of the history's force and displacement
        self.z0 = float(self.direction @ self.centre)  # mm: the centre along it at t = 0
        # face "all": the structure whose free extra nodes (of refined cells, owned, not bound
        # to a border) the body touches too, as found at its node arrays' ``generation``
        self.structure = None
        self.face_mass = 0.0  # tonne: a face node's mass in an unrefined column (face "all")
        # s: the step the faces' in-plane size allows (shortest edge over the fastest wave),
        # the same in every model of one mesh: what a face "all" default penalty is capped for
        self.plane_step: float | None = None
        self.generation = -1
        self.weights = np.ones(len(self.nodes))  # of each node's spring (``add_penalty_forces``)
        self.extra_weights = np.zeros(0)
        self.extra_nodes = np.zeros(0, np.int64)
        self.extra_X = np.zeros((0, 3))
        self.extra_active = np.zeros(0, dtype=bool)
        self.extra_u = None  # the extra nodes' displacement vector (replaced by a refinement)
        self.extra_total = np.zeros(3)
        # mJ, this rank's: the penalty energy of the last evaluation, and the changes of it a
        # refinement made by moving springs between the nodes of a column (split by it: the
        # penetrations differ through the thickness), booked as refinement energy
        self.penalty_local = 0.0
        self.refinement_local = 0.0
        # the face nodes that can touch: erosion releases those it has left without elements
        # (``watch_erosion``)
        self.active = np.ones(len(self.nodes), dtype=bool)
        self._carriers = None  # -> (n_local,) elements of all ranks holding each base node
        # face "all" with erosion: -> (n_owned extra,) the same for the extra nodes, and the
        # owned extra nodes released so far (by owned index: a refinement keeps those)
        self._extra_carriers = None
        self.extra_released = np.zeros(0, dtype=bool)

    def watch_erosion(self, structure) -> None:
        """Collective: from now on ``release`` lets go of the face nodes erosion leaves without
        elements (``report`` calls it at every history row)."""
        damage = structure.ply_damage_state
        n_base = structure.n_base
        counts = la.vector(structure.base.V.dofmap.index_map, bs=1)

        def carriers() -> np.ndarray:
            counts.array[:] = damage.base_node_carriers(n_base)
            counts.scatter_reverse(la.InsertMode.add)  # the other ranks' elements too
            return counts.array

        self._carriers = carriers
        if self.structure is None:
            return
        structure = self.structure

        def extra_carriers() -> np.ndarray:  # (of the extra nodes as they are now)
            extra = structure.extra
            counts = la.vector(extra.index_map, bs=1)
            counts.array[:] = damage.extra_node_carriers(n_base, extra.n_local)
            counts.scatter_reverse(la.InsertMode.add)
            return counts.array[: extra.n_owned]

        self._extra_carriers = extra_carriers

    def release(self) -> None:
        """Collective: stop contact at the face nodes that no element of any rank holds any
        more (erosion has removed them all); a released node carries no force (the normal
        penalty energy it held goes with the body's energy, its tangential spring's is booked
        as dissipated by friction). At
        the history rows only, so that the contact changes at the same times whatever the
        number of ranks (a node on a partition boundary needs the other ranks' elements):
        a node erosion frees keeps its contact until the next row (``output.interval``)."""
        if self._carriers is None:
            return
        # (the friction kernel lets a released node's tangential spring go, booking its
        # energy as dissipated)
        self.active &= self._carriers()[self.nodes] > 0
        if self._extra_carriers is not None:  # a body on every node: the extra nodes too
            carriers = self._extra_carriers()
            self._grow_released(len(carriers))
            self.extra_released[: len(carriers)] |= carriers == 0
            self.extra_active = ~self.extra_released[self.extra_nodes]

    def _grow_released(self, n_owned: int) -> None:
        """``extra_released`` for ``n_owned`` owned extra nodes (a refinement appends new
        owned nodes after the old ones, whose indices it keeps)."""
        if len(self.extra_released) < n_owned:
            grown = np.zeros(n_owned, dtype=bool)
            grown[: len(self.extra_released)] = self.extra_released
            self.extra_released = grown

    def initial_gap(self) -> float:
        """Collective: the smallest gap (mm) between the body and its undeformed face."""
        dx = self.X - self.centre
        if self.axis == PLANE_AXIS:
            distance = dx @ self.normal
        else:
            if self.axis >= 0:
                dx[:, self.axis] = 0.0
            distance = np.linalg.norm(dx, axis=1)
        local = float(np.min(distance)) if len(self.X) else np.inf
        return self.comm.allreduce(local, op=MPI.MIN) - self.body.radius

    def path_clearance(self, direction: np.ndarray) -> float:
        """Collective: how far (mm) the body stays from the nearest node of its face if it
        moved along the whole line through its centre in ``direction`` (3,) with the
        structure undeformed: the smallest distance from a node to that line (a cylinder's:
        across its axis) less the radius. Above zero the body cannot touch the face (unless the
        structure moves across its path); -inf for a plane, which reaches every node along its
        normal."""
        if self.axis == PLANE_AXIS:
            return -np.inf
        d = np.array(direction, dtype=float)
        dx = self.X - self.centre
        if self.axis >= 0:  # a cylinder: in the plane across its axis
            dx[:, self.axis] = 0.0
            d[self.axis] = 0.0
        length = float(np.linalg.norm(d))
        if length > 0.0:
            d /= length
            dx -= np.outer(dx @ d, d)
        local = float(np.linalg.norm(dx, axis=1).min()) if len(dx) else np.inf
        return self.comm.allreduce(local, op=MPI.MIN) - self.body.radius

    def largest_stable_penalty(self, dt: float, element_step: float) -> float:
        """The largest penalty (N/mm) stable with the time step dt (s), for the lightest face
        node of mass m and the body of mass M (infinite unless free): the spring adds
        k (1/m + 1/M) to the square of the node's highest frequency, which its elements already
        bring up to (2 / element_step)^2 (element_step: the element limit without the safety
        factor), and central differences need omega dt <= 2:
        k <= (2/dt)^2 (1 - (dt/element_step)^2) / (1/m + 1/M)."""
        share = max(1.0 - (dt / element_step) ** 2, 0.0)
        return share * (2.0 / dt) ** 2 / (1.0 / self.node_mass_min + 1.0 / self.body.mass)

    def check_penalty(self, dt: float, element_step: float) -> None:
        """Refuse an explicit penalty above ``largest_stable_penalty`` (InputError naming the
        body's penalty key)."""
        if self.body.penalty is None:
            return
        largest = self.largest_stable_penalty(dt, element_step)
        if self.penalty > largest:
            raise InputError(
                f"{self.key}.penalty",
                f"{self.penalty:.4g} N/mm is too stiff for the time step {dt:.4g} s (lightest "
                f"{self.body.face}-face node {self.node_mass_min:.4g} t, body "
                f"{self.body.mass:.4g} t): the largest stable penalty is {largest:.4g} N/mm "
                "(omit it for the default)",
            )

    def limit_penalty(self, dt: float, element_step: float | None = None) -> None:
        """Cap the default penalty for the time step dt (s) (an explicit penalty is kept and
        checked by the caller). On face "all" the cap is for the in-plane step
        (``plane_step``), not the run's: the same default in an ESL, an adaptive and a
        layerwise model of one mesh (whose steps differ with their layers' thickness), and
        below the stable limit at dt (``element_step``: the element limit, s) too."""
        step = dt if self.plane_step is None else self.plane_step
        cap = 0.05 * self.node_mass_min * (2.0 / step) ** 2
        if self.plane_step is not None and element_step is not None:
            cap = min(cap, 0.5 * self.largest_stable_penalty(dt, element_step))
        if self.body.penalty is None:
            self.penalty = min(self.natural_penalty, cap)

    def prepare(self, dt: float, element_step: float) -> None:
        """At the start of a run with the time step dt (s): the default penalty capped, an
        explicit one checked (``element_step``: the structure's stable step without the safety
        factor, s); the body's height taken as its reference."""
        self.limit_penalty(dt, element_step)
        self.check_penalty(dt, element_step)
        self.z0 = float(self.direction @ np.asarray(self.body.position, dtype=float))

    def add_force(self, t: float, f_base: np.ndarray, f_extra: np.ndarray) -> None:
        """Add the contact forces (N) at the current displacement into ``f_base`` (owned base
        DOFs, flat) at the face's DOFs; also the body's force, the acceleration of a free body
        and the work of a driven one's drive. Collective if ``every_step``: the sum over the
        ranks is started here and completed by ``finish`` (or by whoever waits on
        ``pending_request``). ``f_extra`` (owned extra DOFs) gets the forces on the free
        extra nodes of a body on face "all" (the top and bottom faces have none)."""
        self.finish()  # the last evaluation's, if nothing read it (a refinement evaluates twice)
        refined = self.structure is not None and self.follow_refinement()
        energy = self._springs(self.penalty, f_base, self.totals[:3])
        if self.structure is not None:
            if len(self.extra_nodes):
                energy += self._springs(self.penalty, f_extra, self.extra_total, extra=True)
                self.totals[:3] += self.extra_total
            if refined:  # at the state of the last evaluation, springs moved between nodes
                self.refinement_local += energy - self.penalty_local
        self.penalty_local = energy
        self.totals[3] = energy
        if self.friction > 0.0:
            self._add_friction(f_base)
        self.totals[4] = self.friction_local
        self._taken = False
        if self.every_step and self.comm.size > 1:
            self._request = self.comm.Iallreduce(MPI.IN_PLACE, self.totals, op=MPI.SUM)
        else:
            self.finish()

    @property
    def every_node(self) -> bool:
        """Whether the body touches every node (face "all"): edges and ends, not only faces."""
        return self.body.face == "all"

    def take_out_of(self, out: np.ndarray) -> None:
        """Subtract this body's forces on the base nodes at the current displacement from
        ``out`` (N, owned base DOFs, flat): what a body on every node presses is an edge or
        an end as well as a face, and the indicators read only face loads as face tractions
        (``ExplicitSolver.face_force``)."""
        # (the opposite springs; extra_total as scratch: the body's own totals are not touched)
        self._springs(-self.penalty, out, self.extra_total)

    def _springs(
        self, penalty: float, f: np.ndarray, total: np.ndarray, extra: bool = False
    ) -> float:
        """``add_penalty_forces`` of the body's base nodes, or its ``extra`` nodes, with
        ``penalty`` (N/mm) into f (flat, N) and their reaction on the body into ``total``
        (3,); returns the penalty energy (mJ)."""
        if extra:
            u, nodes, active, X = self.extra_u, self.extra_nodes, self.extra_active, self.extra_X
            weights = self.extra_weights
        else:
            u, nodes, active, X = self.displacement, self.nodes, self.active, self.X
            weights = self.weights
        return add_penalty_forces(
            u.array,
            nodes,
            active,
            X,
            self.centre,
            self.body.radius,
            self.axis,
            self.normal,
            penalty,
            weights,
            f,
            total,
        )

    def follow_refinement(self) -> bool:
        """A body on face "all", after each refinement (at its first evaluation since): the
        owned extra nodes it touches, those not bound to the border of a refined region (a
        bound node follows its masters, which the body touches themselves), and every node's
        spring weight m / m_face, m its lumped mass now (the border's transfer made): the
        springs of a column then add up to the same stiffness whatever splits it (an ESL
        column, a refined one, a layerwise one), as its masses do. Returns whether the springs
        changed since an earlier evaluation (not at the first one, nor at a restart's)."""
        structure = self.structure
        generation = structure.node_arrays.generation
        if generation == self.generation:
            return False
        first = self.generation < 0
        self.generation = generation
        bound = np.unique(structure.border.dofs // 3) - structure.n_base  # local extra nodes
        free = np.setdiff1d(np.arange(structure.extra.n_owned), bound).astype(np.int64)
        self.extra_nodes = free
        self.extra_u = structure.extra.vectors["u"]
        X = structure.extra.vectors["X"].array.reshape(-1, 3)
        self.extra_X = np.ascontiguousarray(X[free])
        self._grow_released(structure.extra.n_owned)
        self.extra_active = ~self.extra_released[free]
        self.weights = structure.base_block.mass[3 * self.nodes] / self.face_mass
        self.extra_weights = structure.extra_block.mass[3 * free] / self.face_mass
        return not first

    def _add_friction(self, f_base: np.ndarray) -> None:
        """The friction forces at the current state into ``f_base`` and the body's force;
        their springs' energy into the penalty energy, their dissipation into this rank's."""
        if not self.friction_started:  # the first evaluation: nothing has slid yet
            u = self.displacement.array.reshape(-1, 3)[self.nodes]
            np.add(self.X, u, out=self.previous)
            self.friction_centre[:] = self.centre
            self.friction_started = True
        np.subtract(self.centre, self.friction_centre, out=self.slid)
        springs, dissipated = add_friction_forces(
            self.displacement.array,
            self.nodes,
            self.active,
            self.X,
            self.centre,
            self.slid,
            self.body.radius,
            self.axis,
            self.normal,
            self.penalty,
            self.friction,
            self.previous,
            self.traction,
            f_base,
            self.totals[:3],
        )
        self.friction_centre[:] = self.centre
        self.totals[3] += springs
        self.friction_local += dissipated

    def pending_request(self) -> MPI.Request:
        """The reduction of the body's force under way (``MPI.REQUEST_NULL`` if none): a wait
        on it elsewhere (the internal forces' reverse exchange) completes it; ``finish`` then
        only reads the sums."""
        return self._request

    def finish(self) -> None:
        """The body's force, penalty energy and acceleration (free) or drive work (driven)
        from the last ``add_force``, waiting for their sum over the ranks if it is still under
        way. Idempotent."""
        if self._request:
            self._request.Wait()
        if self._taken:
            return
        self._taken = True
        self.force[:] = self.totals[:3]
        self.energy_penalty = float(self.totals[3])
        self.friction_energy = float(self.totals[4])
        if self.free:
            np.divide(self.force, self.body.mass, out=self.acceleration)
        else:  # the drive holds the body against the structure's force: it applies -force
            np.subtract(self.centre, self.previous_centre, out=self.moved)
            self.drive_work -= 0.5 * float(
                self.previous_force @ self.moved + self.force @ self.moved
            )
            self.previous_centre[:] = self.centre
            self.previous_force[:] = self.force

    def advance(self, mean_dt: float, dt: float) -> None:
        """v_{n-1/2} -> v_{n+1/2}, c_n -> c_{n+1} (a fixed body stays, a prescribed one
        follows its path)."""
        self.finish()
        self.t += dt
        self.last_dt = dt
        if self.free:
            self.velocity += mean_dt * self.acceleration
            self.centre += dt * self.velocity
        elif self.body.motion == RigidMotion.PRESCRIBED:  # in place: no allocation per step
            np.multiply(self.path, self.body.path_scale(self.t), out=self.centre)
            self.centre += self.origin

    def totals_over_ranks(self) -> tuple[np.ndarray, float, float, float]:
        """Collective: (force on the body (3,), N; penalty energy, mJ; the drive's work so far,
        mJ; the energy friction dissipated so far, mJ) over all ranks, at the last
        ``add_force``."""
        self.finish()
        if self.every_step:  # already summed (a free body's drive work stays 0)
            return self.force, self.energy_penalty, self.drive_work, self.friction_energy
        local = np.array([*self.force, self.energy_penalty, self.drive_work, self.friction_energy])
        total = summed(self.comm, local)
        return total[:3], float(total[3]), float(total[4]), float(total[5])

    def total_energy(self) -> float:
        """Kinetic energy at the full step (a free body's) plus the penalty energy (mJ): of the
        whole run if ``every_step``, else this rank's share."""
        self.finish()
        if not self.free:
            return self.energy_penalty
        v = self.velocity + 0.5 * self.last_dt * self.acceleration
        return 0.5 * self.body.mass * float(v @ v) + self.energy_penalty

    def energy(self) -> float:
        """This rank's share of the body's energy (mJ): a body summed every step has all of it
        on rank 0 (one body, known to every rank); the others their own penalty energy."""
        if not self.every_step:
            return self.energy_penalty
        return self.total_energy() if self.comm.rank == 0 else 0.0

    def report(self, row, first: bool) -> None:
        """Collective: the body's force on the structure's opposite (N, along ``direction``: z,
        or minus the normal for a plane, from the structure towards the plane; the force the
        structure applies to it, positive as it pushes a plane back), its displacement along
        the same (mm; a plane moving into the structure has a negative one) and the energy it
        gave since t = 0 (mJ, added to ``impact_work``: the work of the contact forces on the
        structure, net of what friction dissipated, which has its column
        ``<name>_friction_energy``, and of the spring energy refinements moved, which goes
        with ``refinement_energy``) into a history row; ``first``: the row at t = 0."""
        force, penalty, drive_work, friction = self.totals_over_ranks()
        self.release()
        if first:
            self.initial = self.total_energy()
            self.initial_penalty = penalty
        displacement = float(self.direction @ self.centre - self.z0)
        along = float(self.direction @ force)
        if self.body.name == "impactor":
            row.contact_force = along
            row.impactor_displacement = displacement
        else:
            row.bodies[f"{self.body.name}_force"] = along
            row.bodies[f"{self.body.name}_displacement"] = displacement
        if self.friction > 0.0:
            row.bodies[f"{self.body.name}_friction_energy"] = friction
        if self.free:
            row.impact_work += self.initial - self.total_energy() - friction
        else:
            row.impact_work += drive_work - (penalty - self.initial_penalty) - friction
        if self.structure is not None:  # (the same on every rank: a body on face "all")
            row.refinement_energy += summed(self.comm, np.array([self.refinement_local]))[0]

    def suspect(self) -> str:
        return (
            f"the contact penalty ({self.key}.penalty = {self.penalty:.4g} N/mm) too stiff for it?"
        )

    def state(self) -> dict[str, np.ndarray]:
        self.finish()
        if self.structure is not None:
            self._grow_released(self.structure.extra.n_owned)
        return {
            "centre": self.centre.copy(),
            "velocity": self.velocity.copy(),
            "initial": np.array(self.initial),
            "z0": np.array(self.z0),
            "last_dt": np.array(self.last_dt),
            "t": np.array(self.t),
            "initial_penalty": np.array(self.initial_penalty),
            "drive_work": np.array(self.drive_work),
            "previous_centre": self.previous_centre.copy(),
            "previous_force": self.previous_force.copy(),
            "traction": self.traction.copy(),
            "previous": self.previous.copy(),
            "friction_centre": self.friction_centre.copy(),
            "friction_started": np.array(self.friction_started),
            "friction_local": np.array(self.friction_local),
            "active": self.active.copy(),
            "refinement_energy": np.array(self.refinement_local),
            "extra_released": self.extra_released.copy(),
            # the default penalty is capped for the step a run starts with; a restart after a
            # refinement starts with a shorter step, and would cap it higher
            "penalty": np.array(self.penalty),
        }

    def layout(self, structure) -> dict:
        """How the rows of ``state()``'s arrays are indexed (``parallel.redistribute``): the
        face's owned nodes and the owned extra nodes by their stable keys; the forces' work,
        friction and refinement energy as each rank's share (a body summed every step holds
        its totals on every rank)."""
        nodes = Rows(structure.node_keys[self.nodes])
        self._grow_released(structure.extra.n_owned)  # (as ``state`` gives it: every one)
        n_released = len(self.extra_released)
        share = REPLICATED if self.every_step else PARTIAL
        return {
            "traction": nodes,
            "previous": nodes,
            "active": nodes,
            "extra_released": Rows(structure.extra_node_keys()[:n_released], fill=False),
            "drive_work": share,
            "previous_force": share,
            "initial": share,
            "friction_local": PARTIAL,
            "refinement_energy": PARTIAL,
        }

    def restore(self, state: dict) -> None:
        self.finish()  # a reduction of before the restore completes first (every rank has one)
        self.centre[:] = state["centre"]
        self.velocity[:] = state["velocity"]
        self.initial = float(state["initial"])
        self.z0 = float(state["z0"])
        self.last_dt = float(state["last_dt"])
        if "t" in state:  # checkpoints before rigid bodies had a free impactor only
            self.t = float(state["t"])
            self.initial_penalty = float(state["initial_penalty"])
            self.drive_work = float(state["drive_work"])
            self.previous_centre[:] = state["previous_centre"]
            self.previous_force[:] = state["previous_force"]
        if "traction" in state:  # checkpoints before friction had none (frictionless)
            self.traction[:] = state["traction"]
            self.previous[:] = state["previous"]
            self.friction_centre[:] = state["friction_centre"]
            self.friction_started = bool(state["friction_started"])
            self.friction_local = float(state["friction_local"])
        if "active" in state:  # checkpoints before erosion had every node active
            self.active[:] = state["active"]
        self.refinement_local = float(state.get("refinement_energy", 0.0))
        self.extra_released = np.array(state.get("extra_released", ()), dtype=bool)
        if "penalty" in state and self.body.penalty is None:  # (an explicit one: the config's)
            self.penalty = float(state["penalty"])
        self.generation = -1  # (the springs found again at the next evaluation, not booked)
