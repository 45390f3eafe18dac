"""Run a config on this MPI job (as ``fenics-adaptive run`` does) and print, from rank 0, one JSON
line with what each rank held: the x range of its cells, its extra nodes, cohesive elements,
border constraints, the largest ply damage and the largest contact force on its nodes.
tests/test_mpi.py runs it under mpiexec to check that an event happened on one rank only.

Usage: python tests/mpi_case.py CONFIG.toml OUT_DIR
"""

import json
import sys

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
    accelerations need the forward-scattered residual); 0 without a scaled mass."""
    mass = structure.scaled_mass
    if mass is None:
        return 0
    ghost = mass.chain_nodes >= structure.base.V.dofmap.index_map.size_local
    return int(np.add.reduceat(ghost, mass.chain_offsets[:-1]).astype(bool).sum())


def main() -> None:
    comm = MPI.COMM_WORLD
    config = load_config(sys.argv[1])
    _, structure = execute(config, sys.argv[2], comm, show_progress=False, log=None)
    x = structure.cell_vertices()[:, :, 0].mean(axis=1)
    held = {
        "x_min": float(x.min()),
        "x_max": float(x.max()),
        "extra_nodes": structure.extra.n_owned,
        "cohesive": len(structure.cohesive),
        "border": len(structure.border),
        "ply_damage": float(structure.damage_state[:, :, S_D].max())
        if structure.ply_damage
        else 0.0,
        "contact_force": peak_contact[0],
        "columns_with_ghosts": columns_with_ghosts(structure),
    }
    ranks = comm.gather(held)
    if comm.rank == 0:
        print(json.dumps(ranks), flush=True)


if __name__ == "__main__":
    main()
