"""Run under mpiexec by tests/test_halo.py: the halo exchange of two blocks against DOLFINx's own
scatters, on a box mesh, with random values. Prints one JSON line from rank 0."""

import json

import numpy as np
from mpi4py import MPI

comm = MPI.COMM_WORLD  # (mpi4py loaded before DOLFINx)

import dolfinx.la as la  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402

from fenics_adaptive.parallel import Halo  # noqa: E402

box = mesh.create_box(comm, [[0, 0, 0], [4, 1, 1]], [9, 3, 2], mesh.CellType.hexahedron)
spaces = [
    fem.functionspace(box, ("Lagrange", 1, (3,))),
    fem.functionspace(box, ("Lagrange", 1)),
    fem.functionspace(box, ("Lagrange", 2)),  # a map with other ghosts than the first two
]
maps = [V.dofmap.index_map for V in spaces]
sizes = [3, 1, 1]
halo = Halo(comm, maps, sizes)
rng = np.random.default_rng(comm.rank + 1)
values = [la.vector(m, bs=bs) for m, bs in zip(maps, sizes, strict=True)]
for v in values:
    v.array[:] = rng.random(len(v.array))


def difference(direction: str) -> float:
    reference = [la.vector(m, bs=bs) for m, bs in zip(maps, sizes, strict=True)]
    for r, v in zip(reference, values, strict=True):
        r.array[:] = v.array
        if direction == "forward":
            r.scatter_forward()
        else:
            r.scatter_reverse(la.InsertMode.add)
    mine = [v.array.copy() for v in values]
    # a reduction started before the exchange completes in its wait
    flags = np.array([comm.rank + 1.0])
    request = comm.Iallreduce(MPI.IN_PLACE, flags, op=MPI.SUM)
    getattr(halo, direction)(mine, also=[request])
    assert not request and flags[0] == comm.size * (comm.size + 1) / 2
    pairs = zip(mine, reference, strict=True)
    return max(float(np.abs(a - r.array).max(initial=0.0)) for a, r in pairs)


forward, reverse = difference("forward"), difference("reverse")

# a map without ghosts anywhere, and a layered mesh of two columns: on three ranks one rank
# holds no cell and no neighbour, and takes part with empty messages
from dolfinx.cpp.common import IndexMap  # noqa: E402
from fenics_adaptive.meshes.beam import layered_mesh  # noqa: E402

strip = layered_mesh(comm, 10.0, 5.0, 2, 1, [1.0, 1.0], [False]).mesh
lonely = fem.functionspace(strip, ("Lagrange", 1, (3,))).dofmap.index_map
bare = IndexMap(comm, 4)
maps, sizes = [bare, lonely], [2, 3]
halo.free()
halo = Halo(comm, maps, sizes)
values = [la.vector(m, bs=bs) for m, bs in zip(maps, sizes, strict=True)]
for v in values:
    v.array[:] = rng.random(len(v.array))
forward = max(forward, difference("forward"))
reverse = max(reverse, difference("reverse"))
empty_rank = strip.topology.index_map(3).size_local == 0
try:  # a second start before the first exchange finished is refused
    arrays = [v.array for v in values]
    halo.forward_start(arrays)
    halo.forward_start(arrays)
    refused = False
except RuntimeError:
    refused = True
    halo.forward_finish(arrays)
ghosts = comm.gather(halo.ghost_values)
expected = comm.gather(sum(bs * m.num_ghosts for m, bs in zip(maps, sizes, strict=True)))
halo.free()
from threadpoolctl import threadpool_info  # noqa: E402

from fenics_adaptive.parallel import one_thread_per_rank  # noqa: E402

limited = one_thread_per_rank(comm)
threads = [pool["num_threads"] for pool in threadpool_info()]
results = comm.gather(
    {
        "forward": forward,
        "reverse": reverse,
        "refused": refused or comm.size == 1,
        "limited": limited,
        "threads": threads,
        "empty_rank": bool(empty_rank),
    }
)
if comm.rank == 0:
    print(json.dumps({"ranks": results, "ghosts": ghosts, "expected_ghosts": expected}))
