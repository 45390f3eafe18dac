"""# 2. Figure 2 of the paper: subelements, plies and the gather/scatter maps

A cell with seven plies is refined at interfaces 2 and 4. It splits into three subelements:
plies 1-2, plies 3-4 and plies 5-7. This script shows that assignment, shows that the
integration points of the plies do not move, and prints the maps that tell each subelement
which nodes are its eight nodes (the paper's projection matrices P).

Run it from the repository root (serial, about 2 s):

    .venv/bin/python docs/afem/02_figure2_maps.py

Units: N, mm, s, tonne.
"""

# %%
import tomllib
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenics_adaptive import enrichment as enr
from fenics_adaptive.config import parse_config
from fenics_adaptive.runner import build_structure
from fenics_adaptive.subelement import sublaminate_ply_zeta

# %% [markdown]
# ## Interface states decide the subelements
#
# Each cell stores one state per ply interface: `NONE`, `WEAK` or `STRONG`. Every interface that
# is not `NONE` cuts the cell. A subelement is a run of plies between two cuts (or between a cut
# and the bottom or top face of the cell). `enrichment.subelements` returns them as ply ranges
# [first, stop), 0-based, like Python slices.

# %%
n_plies = 7
figure_2 = np.zeros(n_plies - 1, dtype=np.int8)  # interfaces 1..6
figure_2[[2 - 1, 4 - 1]] = enr.WEAK
subelements = enr.subelements(figure_2)
for number, sub in enumerate(subelements, start=1):
    plies = list(range(sub.first + 1, sub.stop + 1))  # 1-based, as in the paper
    print(f"subelement {number}: plies {plies}")
assert [(s.first, s.stop) for s in subelements] == [(0, 2), (2, 4), (4, 7)]

# %% [markdown]
# ## The integration points stay where they are
#
# Each ply has its own layer of integration points. A subelement has its own reference thickness
# coordinate zeta in [0, 1]. `sublaminate_ply_zeta` gives the zeta range of each of its plies.
# Mapped back to the thickness fraction of the whole cell, f = f_first + zeta (f_stop - f_first),
# each ply must land exactly on its own range in the unrefined cell. Then no integration-point
# data (stress history, damage) has to be mapped when a cell refines: each ply's points simply
# change owner.

# %%
# the seven plies of `01_extra_nodes.py`, of unequal thickness (mm)
ply_thickness = np.array([0.15, 0.15, 0.30, 0.30, 0.20, 0.20, 0.20])
fractions = np.concatenate([[0.0], np.cumsum(ply_thickness)]) / ply_thickness.sum()
print("\nply  subelement  zeta range in subelement  fraction range in cell")
for number, sub in enumerate(subelements, start=1):
    zeta = sublaminate_ply_zeta(fractions, sub.first, sub.stop)
    f_first, f_stop = fractions[sub.first], fractions[sub.stop]
    in_cell = f_first + zeta * (f_stop - f_first)
    for k, (lo, hi) in zip(range(sub.first, sub.stop), in_cell, strict=True):
        z_lo, z_hi = zeta[k - sub.first]
        print(f"{k + 1:3d}  {number:10d}  [{z_lo:.3f}, {z_hi:.3f}]            [{lo:.3f}, {hi:.3f}]")
        assert abs(lo - fractions[k]) < 1e-15 and abs(hi - fractions[k + 1]) < 1e-15

# %% [markdown]
# ## A real cell and its maps
#
# One cell, 1 x 0.5 mm in-plane, with the same seven plies. Interface 2 may refine, interface 4
# may also delaminate. We refine both weakly: this is Figure 2. `Structure.cell_maps` prints,
# for each subelement, which node of the structure is its local node k (k = 0-3 bottom face,
# 4-7 top face, DOLFINx vertex order). Node indices below the number of base nodes are base
# nodes; the others are extra nodes, named by interface and set (`i2A`: interface 2, set A).

# %%
data = tomllib.loads((Path(__file__).parent / "seven_plies.toml").read_text())  # Figure 2

assert MPI.COMM_WORLD.size == 1, "run this script in serial"
structure = build_structure(parse_config(data, source="02_figure2_maps"))
cell = 0
structure.refine([(cell, 2, enr.WEAK), (cell, 4, enr.WEAK)])
print("\n" + structure.cell_maps(cell))

# %% [markdown]
# ## The maps as index lists
#
# The maps are stored as 8 node indices per subelement. We rebuild them with
# `enrichment.subelement_nodes` and check them physically: gathering the reference coordinates
# through subelement i's list must give a hexahedron whose bottom face lies at the fraction
# f_first and whose top face lies at f_stop of the cell's thickness.


# %%
def cell_columns(structure, cell):
    """The base nodes of a cell's four columns (local and global indices)."""
    return enr.CellColumns(
        structure.bottom_local[cell], structure.top_local[cell], structure.bottom_global[cell]
    )


def nodes_of(structure, cell, sub):
    """Combined local node indices (8,) of subelement ``sub`` of ``cell``."""
    return enr.subelement_nodes(
        structure.interface_state[cell],
        sub,
        cell_columns(structure, cell),
        structure.laminate.n_plies,
        structure.extra.index,
        structure.n_base,
    )


def gather_X(structure, nodes):
    """Reference coordinates (n, 3) of combined local nodes: the gather P X."""
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    all_X = np.vstack([structure.X_base, X_extra])
    return all_X[nodes]


thickness = structure.laminate.thickness
assert np.allclose(structure.laminate.ply_fractions, fractions, rtol=0.0, atol=1e-15)
for sub in enr.subelements(structure.interface_state[cell]):
    X_sub = gather_X(structure, nodes_of(structure, cell, sub))
    assert np.allclose(X_sub[:4, 2], fractions[sub.first] * thickness, rtol=0, atol=1e-14)
    assert np.allclose(X_sub[4:, 2], fractions[sub.stop] * thickness, rtol=0, atol=1e-14)

# %% [markdown]
# ## The maps as the paper's matrices
#
# The paper writes the gather as X^sublam,i = P^sublam,i X and the scatter as
# P^sublam,i^T f^sublam,i. With one row per local node and one column per node of the cell,
# P^sublam,i has a single 1 in each row. (On degrees of freedom each 1 becomes a 3 x 3
# identity.) The code never forms these matrices: the index list above holds the same
# information. Here we print them once. The mesh has one cell, so the nodes of the cell are
# all the nodes of the structure: 8 base nodes, then the extra nodes.

# %%
cell_nodes = np.concatenate(
    [np.arange(structure.n_base), structure.n_base + np.arange(structure.extra.n_local)]
)
n_cell_nodes = len(cell_nodes)
header = "".join(f"{n:3d}" for n in cell_nodes)
for number, sub in enumerate(enr.subelements(structure.interface_state[cell]), start=1):
    P = np.zeros((8, n_cell_nodes), dtype=int)
    P[np.arange(8), nodes_of(structure, cell, sub)] = 1
    print(f"\nP^sublam,{number} (rows: local nodes 0-7; columns: nodes of the cell)")
    print("    " + header)
    for k, row in enumerate(P):
        print(f"{k:3d} " + "".join(f"{v:3d}" if v else "  ." for v in row))
    X_cell = gather_X(structure, cell_nodes)
    assert np.array_equal(P @ X_cell, gather_X(structure, nodes_of(structure, cell, sub)))
    assert np.all(P.sum(axis=1) == 1)

# %% [markdown]
# ## Interface 4 turns strong
#
# A strong refinement activates set B at interface 4. The subelement above the interface now
# takes set B as its bottom face. A cohesive element joins set A (its lower face) and set B
# (its upper face): that is the map P^coh,4. The ply assignment does not change: a strong
# refinement only unzips an interface that already cuts the cell.

# %%
structure.refine([(cell, 4, enr.STRONG)])
maps = structure.cell_maps(cell)
print("\n" + maps)
assert [(s.first, s.stop) for s in enr.subelements(structure.interface_state[cell])] == [
    (0, 2),
    (2, 4),
    (4, 7),
]
third = maps.split("subelement 3")[1].split("cohesive")[0]
assert "i4B" in third and "i4A" not in third
assert "cohesive element at interface 4" in maps
print("02_figure2_maps: all checks passed")
