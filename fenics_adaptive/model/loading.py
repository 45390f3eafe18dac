"""Time curves, clamps, prescribed motions and face loads, resolved to DOFs of a model.

Units: N, mm, s. A face is named by its group in the mesh (``fenics_adaptive.meshes.beam``: x0, x1,
top, x1_layer3, ...). Components are "x", "y", "z"."""

from __future__ import annotations

import bisect
import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import dolfinx
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.errors import InputError, shared_errors
from fenics_adaptive.model.forms import LayeredModel

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
    kind: str
    value: float
    amplitude: Amplitude
    x_range: tuple[float, float] | None = None  # only the face's nodes with x in it (mm): a
    # line (x, x) or a pad (x_min, x_max) of a support or a load
    key: str = field(default="", compare=False)  # the config key that made it (for errors)

    def displacement(self, t: float) -> float:
        if self.kind == "displacement":
            return self.value * self.amplitude(t)
        return self.value * self.amplitude.integral(t)


@dataclass(frozen=True)
class FaceLoad:
    """A total force (N, vector) spread over a face as a uniform traction, times amplitude(t)."""

    face: str
    force: tuple[float, float, float]
    amplitude: Amplitude
    key: str = field(default="", compare=False)  # the config key that made it (for errors)


def clamp(face: str) -> list[PrescribedMotion]:
    return [
        PrescribedMotion(face, c, "displacement", 0.0, Amplitude.constant(0.0)) for c in COMPONENTS
    ]


@dataclass
class ResolvedLoads:
    """The loading as arrays on the base DOFs of a model: prescribed DOFs with the index of the
    motion that drives each, and one nodal force vector per face load."""

    motions: list[PrescribedMotion]
    fixed: np.ndarray  # owned base DOFs under a prescribed motion (sorted, unique)
    fixed_motion: np.ndarray  # index into ``motions`` for each fixed DOF
    load_vectors: list[np.ndarray]  # one nodal force vector per FaceLoad (owned + ghosts), N
    load_amplitudes: list[Amplitude]
    _scratch: np.ndarray | None = None

    @property
    def constrained(self) -> np.ndarray:
        return self.fixed

    def external_force(self, t: float, out: np.ndarray) -> None:
        out.fill(0.0)
        if self._scratch is None or self._scratch.shape != out.shape:
            self._scratch = np.empty_like(out)
        for vector, amplitude in zip(self.load_vectors, self.load_amplitudes, strict=True):
            scale = amplitude(t)
            if scale != 0.0:
                np.multiply(vector, scale, out=self._scratch)
                out += self._scratch


def face_nodes(
    model: LayeredModel, face: str, x_range: tuple[float, float] | None = None
) -> np.ndarray:
    """Local nodes (owned and ghosts, sorted) on a face group. ``a&b`` names the nodes on both
    face a and face b (for example ``x1&top``: the top edge of the end x1); ``x_range`` keeps
    only those with x_min <= x <= x_max (a line of nodes across the width, or a pad)."""
    names = face.split("&")
    nodes = None
    for name in names:
        beam = model.beam
        facets = beam.facets(name)
        fdim = beam.mesh.topology.dim - 1
        beam.mesh.topology.create_connectivity(fdim, beam.mesh.topology.dim)
        on_face = fem.locate_dofs_topological(model.V, fdim, facets)
        nodes = on_face if nodes is None else np.intersect1d(nodes, on_face)
    if x_range is not None:
        x = model.V.tabulate_dof_coordinates()[nodes, 0]
        tol = 1e-6 * model.beam.length
        nodes = nodes[(x >= x_range[0] - tol) & (x <= x_range[1] + tol)]
    return np.sort(nodes).astype(np.int32)


def face_dofs(
    model: LayeredModel,
    face: str,
    component: str,
    owned_only: bool = True,
    x_range: tuple[float, float] | None = None,
) -> np.ndarray:
    """DOFs (block-unrolled, sorted) of one component on a face group (``face_nodes``): this
    rank's owned ones, or with ``owned_only=False`` also its ghosts."""
    dofs = 3 * face_nodes(model, face, x_range) + COMPONENTS[component]
    if owned_only:
        dofs = dofs[dofs < model.n_owned_dofs]
    return dofs.astype(np.int32)


def face_area(model: LayeredModel, face: str) -> float:
    ds = ufl.Measure("ds", domain=model.mesh, subdomain_data=model.beam.facet_tags)
    tags = model.beam.face_tags[face]
    area = fem.assemble_scalar(fem.form(1.0 * ds(tags)))
    return model.comm.allreduce(area, op=MPI.SUM)


def resolve(
    model: LayeredModel, motions: Sequence[PrescribedMotion], loads: Sequence[FaceLoad]
) -> ResolvedLoads:
    """The motions and loads on this rank's DOFs. Collective (``face_nodes``, the face areas
    and the load vectors). Raises InputError on every rank for a motion's face without nodes and
    for two faces that prescribe a shared DOF differently (found on the ranks holding it)."""
    owner: dict[int, int] = {}
    for k, motion in enumerate(motions):
        dofs = face_dofs(model, motion.face, motion.component, x_range=motion.x_range)
        if model.comm.allreduce(len(dofs), op=MPI.SUM) == 0:
            where = f" at x in {motion.x_range} mm" if motion.x_range is not None else ""
            raise InputError(
                motion.key or "clamp", f"face {motion.face!r}{where} has no nodes to prescribe"
            )
        # a conflict lies on the ranks that hold the shared DOF: every rank learns of it here,
        # before the next motion's collective face lookup
        with shared_errors(model.comm):
            for dof in dofs:
                previous = owner.setdefault(int(dof), k)
                if previous != k and motions[previous] != motion:
                    # the same DOF prescribed twice is fine only if both hold it at zero
                    if not (_is_zero(motions[previous]) and _is_zero(motion)):
                        other = motions[previous]
                        raise InputError(
                            motion.key or other.key or "prescribed",
                            f"{motion.face!r} ({motion.key or 'a symmetry interface'}) and "
                            f"{other.face!r} ({other.key or 'a symmetry interface'}) both "
                            f"prescribe component {motion.component} of the nodes they share, "
                            "differently",
                        )
    fixed = np.array(sorted(owner), dtype=np.int32)
    fixed_motion = np.array([owner[int(d)] for d in fixed], dtype=np.int32)

    vectors = []
    ds = ufl.Measure("ds", domain=model.mesh, subdomain_data=model.beam.facet_tags)
    v = ufl.TestFunction(model.V)
    for load in loads:
        if "&" in load.face:
            raise InputError(
                load.key or "load", f"{load.face!r}: a load acts on one face, not on a&b"
            )
        area = face_area(model, load.face)
        traction = ufl.as_vector([f / area for f in load.force])
        vec = fem.assemble_vector(
            fem.form(ufl.dot(traction, v) * ds(model.beam.face_tags[load.face]))
        )
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
        vec.scatter_forward()
        vectors.append(vec.array.copy())
    return ResolvedLoads(
        list(motions), fixed, fixed_motion, vectors, [load.amplitude for load in loads]
    )


def _motion_key(motion: PrescribedMotion) -> str:
    """The config table a motion comes from, for messages: a clamp holds every component at
    zero, the rest are [[prescribed]] entries (or a symmetry condition, also zero)."""
    return "clamp" if _is_zero(motion) else "prescribed"


def _is_zero(motion: PrescribedMotion) -> bool:
    return motion.value == 0.0 or all(v == 0.0 for v in motion.amplitude.values)


def extra_node_prescriptions(
    motions: Sequence[PrescribedMotion],
    base: LayeredModel,
    extra: enr.ExtraNodes,
    column_top: dict[int, int],
    n_interfaces: int,
) -> np.ndarray:
    """Collective: motion index (into ``motions``) holding each local extra DOF (owned and
    ghosts), -1 for none: a face motion holds an extra node when both base nodes of its column
    (``column_top``: top base node of each bottom one) are on that face; a symmetry interface
    holds u_z of its nodes. The first motion listed wins."""
    prescribed = np.full(3 * extra.n_local, -1, dtype=np.int64)
    if extra.index_map.size_global == 0:  # the same on every rank
        return prescribed
    n_base = base.V.dofmap.index_map.size_local + base.V.dofmap.index_map.num_ghosts
    parts = [enr.key_parts(k, n_interfaces) for k in extra.index]
    local = np.fromiter(extra.index.values(), dtype=np.int64)
    bottom = np.array([extra.local_base_node(g) for g, _, _ in parts], dtype=np.int64)
    top = np.array([column_top[b] for b in bottom], dtype=np.int64)
    interface = np.array([i for _, i, _ in parts], dtype=np.int64)
    for m, motion in enumerate(motions):
        if motion.face.startswith("interface"):
            on = interface == int(motion.face.removeprefix("interface"))
        else:  # face_nodes is collective: every rank, also one without extra nodes
            mask = np.zeros(n_base, dtype=bool)
            mask[face_nodes(base, motion.face, motion.x_range)] = True
            on = mask[bottom] & mask[top]
        dofs = 3 * local[on] + COMPONENTS[motion.component]
        dofs = dofs[prescribed[dofs] < 0]
        prescribed[dofs] = m
    return prescribed
