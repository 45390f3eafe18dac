"""Benchmark rows ``refined`` (issue 21): what a refined cell costs against the layerwise (LW)
cells and cohesive elements it replaces, and where its time goes.

Units: seconds, cells (columns of the TCB beam), N, mm.

- ``weak cell``: every cell of the TCB beam weakly refined at interfaces 2, 4 and 6 (four
  two-ply subelements, no cohesive element) against the LW beam of four two-ply cell layers
  with shared nodes;
- ``strong cell``: strongly refined at 2 and 6, weak at 4 (four subelements, two cohesive
  elements) against the LW beam of four two-ply layers with cohesive elements at 2 and 6 [at
  most 1.1 x];
- both elastic and with the ply damage update;
- ``TCB refined from the start``: the demo's whole explicit step (``demos/tcb.toml``, 100
  columns) against its LW reference [at most 1.0 x];
- ``profile``: the parts of the strong cells' internal force: gathering the nodes, the
  subelement kernel, scattering the forces, the cohesive elements, the reverse scatter.

Each pair is timed interleaved (adaptive, LW, adaptive, ...; medians), so that the machine's
drift falls on both. Each pair is also a check: both models are given the same smooth
displacement field at their nodes (which are at the same places: the extra nodes of Eq. (1)
lie on the LW layer boundaries), and their stored energies must agree to round-off.
"""

from __future__ import annotations

import statistics
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import mpi4py  # noqa: F401  (before dolfinx)
import numpy as np
from dolfinx import la
from numba import njit

from fenics_adaptive.analysis.studies import tcb_variant
from fenics_adaptive.analysis.timing import time_per_step
from fenics_adaptive.element.subelement import gather_nodes, scatter_add_nodes
from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces
from fenics_adaptive.model.border import transfer_forces
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.settings.solver import Probe
from fenics_adaptive.simulation import build_structure

ROOT = Path(__file__).resolve().parents[1]

# interface states of every cell of each pattern (refinement order: weak first)
PATTERNS = {
    "weak": [(2, InterfaceState.WEAK), (4, InterfaceState.WEAK), (6, InterfaceState.WEAK)],
    "strong": [(4, InterfaceState.WEAK), (2, InterfaceState.STRONG), (6, InterfaceState.STRONG)],
}


def pair_configs(beam: dict, pattern: str) -> tuple[dict, dict]:
    """(adaptive, layerwise) configs of the beam ``beam`` (an adaptive TCB config) for a
    refinement ``pattern``: the LW model has a cell layer per subelement and cohesive elements
    where the pattern is strong."""
    adaptive = {k: dict(v) if isinstance(v, dict) else v for k, v in beam.items()}
    layerwise = {k: dict(v) if isinstance(v, dict) else v for k, v in beam.items()}
    layerwise["model"] = {**beam["model"], "kind": "layerwise"}
    layerwise["mesh"] = {**beam["mesh"], "layers": [2, 2, 2, 2]}
    strong = [i for i, state in PATTERNS[pattern] if state == InterfaceState.STRONG]
    layerwise["interfaces"] = {"delaminate": strong, "symmetry": [4]}
    if not strong:
        layerwise.pop("cohesive")
    return adaptive, layerwise


def refine_every_cell(structure, pattern: str) -> None:
    """Refine all owned cells with ``PATTERNS[pattern]``, weak requests first."""
    cells = range(structure.base.n_owned_cells)
    for kind in (InterfaceState.WEAK, InterfaceState.STRONG):
        requests = [(c, i, s) for c in cells for i, s in PATTERNS[pattern] if s == kind]
        structure.refine(requests)


def impose_field(structure) -> None:
    """u(X) = a smooth bending-like field (strains ~1e-4) at every node, base and extra: both
    models of a pair then hold the same displacement field."""
    for X, u in (
        (structure.X_base, structure.base.u.x.array),
        (structure.extra.vectors["X"].array, structure.extra.vectors["u"].array),
    ):
        X = X.reshape(-1, 3)
        u = u.reshape(-1, 3)
        x, z = X[:, 0] / 50.0, X[:, 2] - 1.024
        u[:, 0] = -2e-4 * z * x + 1e-5 * np.sin(3.0 * X[:, 1])
        u[:, 1] = 3e-5 * z * x
        u[:, 2] = 5e-3 * x**2 + 2e-5 * z**2


def interleaved(calls: dict[str, Callable[[], object]], repeat: int) -> dict[str, float]:
    """Median seconds of each call, timed in turns (one warm-up call each first)."""
    for call in calls.values():
        call()
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeat):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(t) for name, t in times.items()}


def bench_cells(n_cells: int, repeat: int) -> list[dict]:
    """Internal force per cell of weakly and strongly refined beams against their LW beams,
    elastic and with ply damage, and the energies of the same field in both."""
    from run import beam_config  # benchmarks/run.py: the TCB beam scaled up

    rows = []
    for ply_damage in (False, True):
        for pattern in PATTERNS:
            adaptive, layerwise = (
                build_structure(parse_config(data))
                for data in pair_configs(beam_config(n_cells, ply_damage=ply_damage), pattern)
            )
            refine_every_cell(adaptive, pattern)
            energies = []
            for structure in (adaptive, layerwise):
                impose_field(structure)
                structure.internal_force()
                energies.append(sum(structure.internal_forces.energies()))
            seconds = interleaved(
                {"adaptive": adaptive.internal_force, "layerwise": layerwise.internal_force},
                repeat,
            )
            n = adaptive.base.n_owned_cells
            rows.append(
                {
                    "benchmark": "refined",
                    "case": f"{pattern} cell, {'ply damage' if ply_damage else 'elastic'}",
                    "cells": n,
                    "seconds": seconds["adaptive"],
                    "us_per_cell": 1e6 * seconds["adaptive"] / n,
                    "layerwise_us_per_cell": 1e6 * seconds["layerwise"] / n,
                    "over_layerwise": seconds["adaptive"] / seconds["layerwise"],
                    "energy_difference": abs(energies[0] - energies[1]) / abs(energies[1]),
                }
            )
    return rows


def bench_tcb(steps: int, repeat: int) -> list[dict]:
    """The TCB demo's whole explicit step, refined from the start against its LW reference
    (interleaved runs of ``steps`` steps from rest)."""
    base = tomllib.loads((ROOT / "demos" / "tcb.toml").read_text())
    structures = {
        name: build_structure(parse_config(tcb_variant(base, name)))
        for name in ("refined_from_start", "reference")
    }
    probe = Probe("x1&top", "x1&top", "z")
    times: dict[str, list[float]] = {name: [] for name in structures}
    for _ in range(repeat):
        for name, structure in structures.items():
            times[name].append(time_per_step(structure, probe, steps, 1)[0])
    refined, reference = (statistics.median(times[name]) for name in structures)
    n = structures["refined_from_start"].base.n_owned_cells
    return [
        {
            "benchmark": "refined",
            "case": "TCB refined from the start, whole step",
            "cells": n,
            "seconds": refined,
            "us_per_cell": 1e6 * refined / n,
            "layerwise_us_per_cell": 1e6 * reference / n,
            "over_layerwise": refined / reference,
        }
    ]


@njit(cache=True)
def _gather_only(element_nodes, X_base, X_extra, u_base, u_extra) -> float:
    """A one-element-at-a-time gather of the subelements' nodes alone (its result summed so
    that it is not optimised away): the memory traffic of the batched kernel's gather, which
    reads the same entries lane by lane."""
    n_base = X_base.shape[0]
    X = np.empty((8, 3))
    u = np.empty((8, 3))
    total = 0.0
    for e in range(element_nodes.shape[0]):
        gather_nodes(element_nodes[e], n_base, X_base, X_extra, X)
        gather_nodes(element_nodes[e], n_base, u_base, u_extra, u)
        total += X[7, 2] + u[7, 2]
    return total


@njit(cache=True)
def _scatter_only(element_nodes, n_base, f_base, f_extra) -> None:
    """A one-element-at-a-time scatter of a unit force onto the subelements' nodes alone (the
    batched kernel's scatter adds the same entries lane by lane)."""
    f = np.ones((8, 3))
    for e in range(element_nodes.shape[0]):
        scatter_add_nodes(element_nodes[e], n_base, f, 1.0, f_base, f_extra)


def force_profile(structure, repeat: int) -> dict[str, float]:
    """Median seconds of each part of ``structure.internal_force`` in its present state: each
    contributor (the solids, elastic or damaged, and the cohesive elements), the solids' whole
    cells and subelements apart, the subelements' gather and scatter alone, the border's force
    transfer, the reverse scatter; "whole internal force" first."""
    lumped = structure.lumped
    f_base, f_extra = lumped._f_arrays
    node_args = structure.node_arrays.kernel_arguments(f_base, f_extra)
    X_base, X_extra, u_base, u_extra, fb, fe = node_args
    nodes = structure.refined_cells.subelements.nodes
    parts: dict[str, Callable[[], object]] = {"whole internal force": structure.internal_force}
    n_sub = len(structure.refined_cells.subelements)
    for contributor in structure.internal_forces.contributors:
        parts[contributor.name] = lambda c=contributor: c.add_force(0.0, f_base, f_extra)
        # one kernel for all solids: time the whole cells and the subelements apart (the
        # subelements are the last elements)
        if contributor.name == "ply":
            n_all = len(contributor.damage.elements[0])
            time_part = _damaged_part
        elif contributor.name == "solid":
            n_all = len(contributor.solids)
            time_part = _elastic_part
        else:
            continue
        for label, part in (
            ("whole cells", slice(0, n_all - n_sub)),
            ("subelements", slice(n_all - n_sub, n_all)),
        ):
            if time_part is _elastic_part:  # the part's element set made once, not timed
                part = _elastic_set(contributor, part)
            parts[f"{contributor.name}, {label}"] = lambda c=contributor, p=part, f=time_part: f(
                c, p, node_args
            )
    parts["subelements: gather alone"] = lambda: _gather_only(
        nodes, X_base, X_extra, u_base, u_extra
    )
    parts["subelements: scatter alone"] = lambda: _scatter_only(nodes, len(X_base), fb, fe)
    if len(lumped.border):
        parts["border transfer"] = lambda: transfer_forces(*lumped._border_args, f_base, f_extra)
    parts["reverse scatter"] = lambda: (
        lumped.f_base.scatter_reverse(la.InsertMode.add),
        lumped.f_extra.scatter_reverse(la.InsertMode.add),
    )
    return interleaved(parts, repeat)


def _elastic_set(contributor, part: slice) -> SubelementSet:
    """The elastic solids' elements ``part`` as a set of their own."""
    solids = contributor.solids
    return SubelementSet(solids.nodes[part], solids.rule_of_element[part], solids.rules)


def _elastic_part(contributor, elements: SubelementSet, node_args: tuple) -> None:
    """The elastic solids' kernel on ``elements`` (``_elastic_set``) only."""
    add_subelement_forces(elements, *node_args, contributor.model.finite)


def _damaged_part(contributor, part: slice, node_args: tuple) -> None:
    """The damaged solids' kernel on the elements ``part`` only, at the damage as it is (with
    the model's kinematics: co-rotated frames under finite ones)."""
    contributor.damage.add_forces(
        contributor.rule_table.packed,
        *node_args,
        update=False,
        part=part,
        corotational=contributor.model is not None and contributor.model.finite,
    )


def profile_rows(
    case: str, structure, seconds: dict[str, float], benchmark: str = "refined"
) -> list[dict]:
    """Rows of a ``force_profile``: seconds, per cell, share of the whole internal force."""
    whole = seconds["whole internal force"]
    n = structure.base.n_owned_cells
    return [
        {
            "benchmark": benchmark,
            "case": f"{case}: {name}",
            "cells": n,
            "seconds": value,
            "us_per_cell": 1e6 * value / n,
            "share_of_force": value / whole,
        }
        for name, value in seconds.items()
    ]


def bench_profile(n_cells: int, repeat: int) -> list[dict]:
    """Where the internal force of strongly refined cells goes (elastic)."""
    from run import beam_config

    adaptive, _ = pair_configs(beam_config(n_cells), "strong")
    structure = build_structure(parse_config(adaptive))
    refine_every_cell(structure, "strong")
    impose_field(structure)
    return profile_rows("profile, strong cells", structure, force_profile(structure, repeat))


def bench_refined(n_cells: int, steps: int, repeat: int) -> list[dict]:
    """All ``refined`` rows (module docstring)."""
    rows = bench_cells(n_cells, repeat)
    rows += bench_tcb(max(steps, 200), repeat)
    rows += bench_profile(n_cells, repeat)
    return rows
