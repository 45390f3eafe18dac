"""Run under mpiexec by tests/test_scaling_model.py: the ghost nodes of DOLFINx's partition of
plates (the code's own mesh generator), per rank. Prints one JSON line from rank 0."""

import json

from fenics_adaptive.meshes.beam import layered_mesh
from mpi4py import MPI

comm = MPI.COMM_WORLD
out = []
# (nx, ny, layer thicknesses (mm), split boundaries): ESL plates, a layerwise one of four
# sublaminates with cohesive (split) interfaces, a strip
for nx, ny, layers, split in (
    (40, 40, [2.0], []),
    (60, 30, [2.0], []),
    (30, 30, [0.5] * 4, [True] * 3),
):
    mesh = layered_mesh(comm, 50.0, 50.0 * ny / nx, nx, ny, layers, split).mesh
    ghosts = comm.gather(mesh.geometry.index_map().num_ghosts)
    if comm.rank == 0:
        node_layers = len(layers) + 1 + sum(split)
        out.append({"nx": nx, "ny": ny, "layers": node_layers, "ghosts": ghosts})
if comm.rank == 0:
    print(json.dumps(out))
