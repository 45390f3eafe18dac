# %% [markdown]
# # 2. Figure 2 of the paper: subelements, plies and the gather/scatter maps
#
# A cell with seven plies is refined at interfaces 2 and 4. It splits into three subelements:
# plies 1-2, plies 3-4 and plies 5-7. This script shows that assignment, shows that the
# integration points of the plies do not move, prints the maps that tell each subelement
# which nodes are its eight nodes (the paper's projection matrices P), and draws both.
#
# Run it from the repository root (serial, about 2 s):
#
#     .venv/bin/python docs/afem/02_figure2_maps.py
#
# Units: N, mm, s, tonne.

# %%
import tomllib

import matplotlib.pyplot as plt
import numpy as np
from afem_figures import TUTORIAL_DIR, draw_plies, finish
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.solid_shell import gauss_legendre_01
from fenics_adaptive.element.subelement import sublaminate_ply_zeta
from fenics_adaptive.model.diagnostics import cell_maps
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

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
figure_2[[2 - 1, 4 - 1]] = InterfaceState.WEAK
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
# ### The picture: Figure 2
#
# Left, the cell before refinement: seven plies, each with its two Gauss points through the
# thickness (`points_per_ply = 2`; the crosses). Right, the same cell cut at interfaces 2 and
# 4 and drawn apart: three subelements, each with its own thickness coordinate zeta from 0 to
# 1. Each ply keeps its colour and its points. The dotted lines join a point in the cell to
# the same point in its subelement: they are horizontal because the heights are equal, which
# the loop below also asserts. This is the rule ply by ply (`thickness_integration =
# "plies"`); the default pre-integrated rule gives every (sub)element three points whose
# stiffnesses carry its plies' moments (`solid_shell.thickness_rule`), so a refinement moves
# the points, while the integral of the strain energy of a flat cell stays exact under both.

# %%
gauss, _ = gauss_legendre_01(2)
sub_colours = ["#9ecae1", "#fdd0a2", "#c7e9c0"]
fig, (ax_cell, ax_sub) = plt.subplots(1, 2, figsize=(8, 4), sharey=True)
draw_plies(ax_cell, (0.0, 1.0), fractions, 1.0)
gap = 0.06  # drawing gap between the subelements, as a thickness fraction
for number, sub in enumerate(subelements):
    lo, hi = fractions[sub.first], fractions[sub.stop]
    shift = gap * number
    ax_sub.fill_between([0, 1], lo + shift, hi + shift, color=sub_colours[number], lw=0)
    ax_sub.plot([0, 1, 1, 0, 0], [lo + shift, lo + shift, hi + shift, hi + shift, lo + shift], "k")
    ax_sub.text(
        1.03,
        0.5 * (lo + hi) + shift,
        f"subelement {number + 1}\nplies {sub.first + 1}-{sub.stop}",
        va="center",
        fontsize=8,
    )
    zeta = sublaminate_ply_zeta(fractions, sub.first, sub.stop)
    for k, (z_lo, z_hi) in zip(range(sub.first, sub.stop), zeta, strict=True):
        in_cell = fractions[k] + (fractions[k + 1] - fractions[k]) * gauss
        in_sub = lo + (z_lo + (z_hi - z_lo) * gauss) * (hi - lo)  # zeta -> fraction of the cell
        assert np.allclose(in_sub, in_cell, rtol=0.0, atol=1e-15)
        ax_cell.plot([0.5] * 2, in_cell, "kx", ms=5)
        ax_sub.plot([0.5] * 2, in_sub + shift, "kx", ms=5)
        ax_sub.text(
            0.04,
            0.5 * (fractions[k] + fractions[k + 1]) + shift,
            f"ply {k + 1}",
            va="center",
            fontsize=7,
            color="0.3",
        )
        for z_point in in_cell:
            ax_cell.annotate(
                "",
                xy=(1.0, z_point),
                xytext=(0.5, z_point),
                arrowprops={"arrowstyle": "-", "ls": ":", "color": "0.5"},
            )
for interface in (2, 4):
    ax_cell.axhline(fractions[interface], color="k", lw=2.5)
    ax_cell.text(1.02, fractions[interface], f"interface {interface}", va="center", fontsize=8)
ax_cell.set(xlim=(0, 1.35), ylabel="thickness fraction of the cell", xticks=[])
ax_cell.set_title("the cell: 7 plies, cuts at interfaces 2 and 4", fontsize=10)
ax_sub.set(xlim=(0, 1.45), xticks=[])
ax_sub.set_title("three subelements, drawn apart", fontsize=10)
finish(fig, "02_figure2_subelements")

# %% [markdown]
# ## A real cell and its maps
#
# One cell, 1 x 0.5 mm in-plane, with the same seven plies. Interface 2 may refine, interface 4
# may also delaminate. We refine both weakly: this is Figure 2. `diagnostics.cell_maps` prints,
# for each subelement, which node of the structure is its local node k (k = 0-3 bottom face,
# 4-7 top face, DOLFINx vertex order). Node indices below the number of base nodes are base
# nodes; the others are extra nodes, named by interface and set (`i2A`: interface 2, set A).

# %%
data = tomllib.loads((TUTORIAL_DIR / "seven_plies.toml").read_text())  # Figure 2

assert MPI.COMM_WORLD.size == 1, "run this script in serial"
structure = build_structure(parse_config(data, source="02_figure2_maps"))
cell = 0
structure.refine([(cell, 2, InterfaceState.WEAK), (cell, 4, InterfaceState.WEAK)])
print("\n" + cell_maps(structure, cell))

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
# The paper writes the gather as
#
# $$X^{\mathrm{sublam},i} = P^{\mathrm{sublam},i} X$$
#
# and the scatter as $P^{\mathrm{sublam},i\,T} f^{\mathrm{sublam},i}$. With one row per local
# node and one column per node of the cell, $P^{\mathrm{sublam},i}$ has a single 1 in each row.
# (On degrees of freedom each 1 becomes a 3 x 3 identity.) The code never forms these
# matrices: the index list above holds the same information. Here we print them once. The
# mesh has one cell, so the nodes of the cell are all the nodes of the structure: 8 base
# nodes, then the extra nodes.

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
structure.refine([(cell, 4, InterfaceState.STRONG)])
maps = cell_maps(structure, cell)
print("\n" + maps)
assert [(s.first, s.stop) for s in enr.subelements(structure.interface_state[cell])] == [
    (0, 2),
    (2, 4),
    (4, 7),
]
third = maps.split("subelement 3")[1].split("cohesive")[0]
assert "i4B" in third and "i4A" not in third
assert "cohesive element at interface 4" in maps

# %% [markdown]
# ### The picture: the projection matrices
#
# The matrices of the strongly refined cell drawn as grids, one row per local node of the
# subelement or cohesive element, one column per node of the cell. A filled square is a 1.
# The extra nodes are named by interface, set and column (`4B2`: interface 4, set B, column
# 2). Each row has one 1. Subelement 3 takes its bottom face from set B of interface 4 and
# subelement 2 its top face from set A, and P^coh,4 joins the two.

# %%
cell_nodes = np.concatenate(
    [np.arange(structure.n_base), structure.n_base + np.arange(structure.extra.n_local)]
)
names = [str(n) for n in range(structure.n_base)] + [""] * structure.extra.n_local
n_interfaces = n_plies - 1
bottom_column = {int(b): c for c, b in enumerate(structure.bottom_global[cell])}
for key, local in structure.extra.index.items():
    global_bottom, interface, node_set = enr.key_parts(key, n_interfaces)
    names[structure.n_base + local] = f"{interface}{'AB'[node_set]}{bottom_column[global_bottom]}"
state = structure.interface_state[cell]
maps = [
    (f"$P^{{\\mathrm{{sublam}},{n}}}$", nodes_of(structure, cell, sub))
    for n, sub in enumerate(enr.subelements(state), start=1)
]
maps.append(
    (
        "$P^{\\mathrm{coh},4}$",
        enr.cohesive_nodes(
            cell_columns(structure, cell), 4, n_plies, structure.extra.index, structure.n_base
        ),
    )
)
fig, axes = plt.subplots(len(maps), 1, figsize=(8, 9), sharex=True)
for ax, (title, nodes) in zip(axes, maps, strict=True):
    P = np.zeros((8, len(cell_nodes)))
    P[np.arange(8), nodes] = 1.0
    assert np.all(P.sum(axis=1) == 1.0)
    ax.imshow(P, cmap="Greys", vmin=0, vmax=1.4, aspect="equal")
    ax.set_xticks(np.arange(len(cell_nodes)) - 0.5, minor=True)
    ax.set_yticks(np.arange(8) - 0.5, minor=True)
    ax.grid(which="minor", color="0.75", lw=0.5)
    ax.tick_params(which="minor", length=0)
    ax.set_yticks(range(8))
    ax.set_ylabel(title, fontsize=9)
axes[-1].set_xticks(range(len(cell_nodes)), names, rotation=90, fontsize=8)
axes[-1].set_xlabel("nodes of the cell: base nodes 0-7, then extra nodes")
finish(fig, "02_projection_matrices")

# %%
print("02_figure2_maps: all checks passed")
