"""Run a config on this MPI job (as ``fenics-adaptive run`` does) and print, from rank 0, one JSON
line with what each rank held: the x range of its cells, its extra nodes, cohesive elements,
border constraints, the largest ply damage and the largest contact force on its nodes; with a
scaled mass, the chains that hold another rank's node and how well the response to a late
force holds M_s z = w across the ranks.
tests/test_mpi.py runs it under mpiexec to check that an event happened on one rank only.

Usage: python tests/mpi_case.py CONFIG.toml OUT_DIR
"""

import json
import sys
import traceback

import numpy as np
from mpi4py import MPI

from fenics_adaptive.materials.ply_damage import S_D
from fenics_adaptive.model import contact as contact_module
from fenics_adaptive.runner import execute
from fenics_adaptive.settings.config import load_config

# the largest contact force on this rank's nodes over the run (N): recorded around add_force
peak_contact = [0.0]
add_force = contact_module.Contact.add_force


def recording_add_force(self, t, f_base, f_extra):
    before = f_base.copy()
    add_force(self, t, f_base, f_extra)
    if len(f_base):
        peak_contact[0] = max(peak_contact[0], float(np.abs(f_base - before).max()))


contact_module.Contact.add_force = recording_add_force


def columns_with_ghosts(structure) -> int:
    """The chains of a selectively scaled mass that hold a node another rank owns (their
    ranks solve them with their shares of the residual); 0 without a scaled mass."""
    mass = structure.scaled_mass
    if mass is None:
        return 0
    ghost = mass.chain_nodes >= structure.base.V.dofmap.index_map.size_local
    return int(np.add.reduceat(ghost, mass.chain_offsets[:-1]).astype(bool).sum())


def late_response_errors(structure) -> tuple[float, float]:
    """Collective: how far the scaled mass's response z to a force shape w (one that loads
    every column, the partition's border's too: w_z = 1 + x) is from M_s z = w on the free
    owned DOFs (relative to w), and its reaction shares from (M_s z)_p (relative to the
    largest); (0, 0) without a scaled mass. M_s z comes from ``multiply``, which reads the
    ghosts' z by a forward scatter: a path independent of the shares' summation."""
    mass = structure.scaled_mass
    if mass is None:
        return 0.0, 0.0
    n = mass.n_owned_dofs
    shape = np.zeros(n)
    shape[2::3] = 1.0 + structure.X_base[: n // 3, 0]
    z, shares = mass.responses(shape[None, :])
    Mz = mass.multiply(z[0], np.empty(n))
    free = ~mass.prescribed[:n]
    force = float(np.abs(Mz[free] - shape[free]).max(initial=0.0) / shape.max())
    reaction = float(np.abs(shares[0] - Mz[mass.fixed]).max(initial=0.0) / np.abs(Mz).max())
    return force, reaction


def main() -> None:
    comm = MPI.COMM_WORLD
    config = load_config(sys.argv[1])
    _, structure = execute(config, sys.argv[2], comm, show_progress=False, log=None)
    x = structure.cell_vertices()[:, :, 0].mean(axis=1)
    response_force, response_reaction = late_response_errors(structure)
    held = {
        "x_min": float(x.min(initial=np.inf)),  # (a rank may own no cell)
        "x_max": float(x.max(initial=-np.inf)),
        "cells": int(structure.base.n_owned_cells),
        "extra_nodes": structure.extra.n_owned,
        "cohesive": len(structure.cohesive),
        "border": len(structure.border),
        "ply_damage": float(structure.damage_state[:, :, S_D].max())
        if structure.ply_damage
        else 0.0,
        "contact_force": peak_contact[0],
        "columns_with_ghosts": columns_with_ghosts(structure),
        "late_response_force": response_force,
        "late_response_reaction": response_reaction,
    }
    ranks = comm.gather(held)
    if comm.rank == 0:
        print(json.dumps(ranks), flush=True)


if __name__ == "__main__":
    try:
        main()
    except BaseException:
        # an error on one rank leaves the others waiting in a collective: end the whole job,
        # so that the test fails with this traceback instead of at its timeout
        traceback.print_exc()
        sys.stderr.flush()
        MPI.COMM_WORLD.Abort(1)
