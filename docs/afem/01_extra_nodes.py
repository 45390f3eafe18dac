# %% [markdown]
# # 1. Where the extra nodes go: Eq. (1) of the paper
#
# An adaptive cell is one 8-node solid-shell hexahedron through the whole laminate. Refining it
# at ply interface i adds four *extra nodes*, one on each vertical edge of the cell, at the
# height of that interface. This script refines a two-cell strip, checks that every extra node
# sits where Eq. (1) of the paper puts it, and draws the strip with its extra nodes.
#
# Run it from the repository root (serial, about 2 s):
#
#     .venv/bin/python docs/afem/01_extra_nodes.py
#
# Units: N, mm, s, tonne.

# %% [markdown]
# ## The rule
#
# A cell has 8 base nodes: 0-3 on its bottom face and 4-7 on its top face, node a + 4 straight
# above node a. The pair (a, a + 4) is a *column*. Ply interface i (1-based) lies between ply i
# and ply i + 1. Its thickness fraction is
#
# $$\alpha_i = \frac{t_1 + \dots + t_i}{t_1 + \dots + t_n}$$
#
# with $t_k$ the ply thicknesses. The extra node of column a at interface i sits at
#
# $$X = \hat{X}_a + \alpha_i \left(\hat{X}_{a+4} - \hat{X}_a\right)
# \qquad \text{(paper, Eq. 1)}$$
#
# where $\hat{X}$ are the reference positions of the base nodes. The rule uses only the column, so
# it holds for tapered or skewed cells too.
#
# The paper numbers the nodes of an element subelement by subelement, so each interface point
# appears twice in its Eq. (1): as a top node of subelement i and as a bottom node of subelement
# i + 1 (X_{8(i-1)+5} = X_{8i+1}). Here every node is stored once, and the subelements refer to
# it by index (`02_figure2_maps.py`).

# %%
import tomllib

import matplotlib.pyplot as plt
import numpy as np
from afem_figures import SET_COLOURS, TUTORIAL_DIR, draw_plies, finish
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

# %% [markdown]
# ## The model
#
# The seven plies of unequal thickness of `seven_plies.toml` (the Figure 2 cell of the next two
# scripts), so that the fractions alpha_i are not evenly spaced. Here two cells side by side
# along x, and every interface may refine; interface 4 may also turn strong. The clamp, solver
# and output sections are required by the config parser but unused: nothing is time-integrated.

# %%
data = tomllib.loads((TUTORIAL_DIR / "seven_plies.toml").read_text())
data["mesh"].update(length=2.0, nx=2)  # two cells side by side
data["interfaces"]["refine"] = [1, 2, 3, 5, 6]  # and 4 (delaminate): every interface

assert MPI.COMM_WORLD.size == 1, "run this script in serial"
structure = build_structure(parse_config(data, source="01_extra_nodes"))
laminate = structure.laminate

# %% [markdown]
# ## The fractions alpha_i
#
# The laminate computes alpha_i from the ply thicknesses. We compute them again by hand.

# %%
thickness = np.array([ply.thickness for ply in laminate.plies])
alpha_by_hand = np.cumsum(thickness)[:-1] / thickness.sum()
alpha = laminate.interface_fractions
print("interface  alpha_i")
for i, a in enumerate(alpha, start=1):
    print(f"{i:9d}  {a:.6f}")
assert np.allclose(alpha, alpha_by_hand, rtol=0.0, atol=1e-15)

# %% [markdown]
# ## Refine, in an arbitrary order
#
# The left cell refines at interface 4 first, then 2, then 6, in three separate steps. The right
# cell refines at interface 4 only. A new extra node takes its position (and its displacement and
# velocity) by linear interpolation between the closest active nodes below and above it in its
# column. When interface 2 refines after interface 4, its nodes are interpolated between the
# bottom base node and the interface-4 node. In exact arithmetic this is again Eq. (1); below we
# check that round-off keeps it so.

# %%
centroid_x = structure.X_base[structure.bottom_local].mean(axis=1)[:, 0]
left, right = (int(c) for c in np.argsort(centroid_x))
for interface in (4, 2, 6):
    structure.refine([(left, interface, InterfaceState.WEAK)])
structure.refine([(right, 4, InterfaceState.WEAK)])

# %% [markdown]
# ## Check every extra node against Eq. (1)
#
# An extra node is known by a key: (bottom base node of its column, interface, set). We decode
# the key, find the column's two base nodes, and compare. We also recover the fraction from the
# position, s = (X - X_bottom) . (X_top - X_bottom) / |X_top - X_bottom|^2, which must equal
# alpha_i.

# %%
n_interfaces = laminate.n_plies - 1
X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
worst_position, worst_fraction = 0.0, 0.0
rows = []
for key, local in structure.extra.index.items():
    global_bottom, interface, node_set = enr.key_parts(key, n_interfaces)
    bottom = structure.extra.local_base_node(global_bottom)
    top = structure.columns.top_of[bottom]
    X_bottom, X_top = structure.X_base[bottom], structure.X_base[top]
    expected = X_bottom + alpha[interface - 1] * (X_top - X_bottom)
    edge = X_top - X_bottom
    fraction = (X_extra[local] - X_bottom) @ edge / (edge @ edge)
    worst_position = max(worst_position, np.abs(X_extra[local] - expected).max())
    worst_fraction = max(worst_fraction, abs(fraction - alpha[interface - 1]))
    if bottom == structure.bottom_local[left, 0]:
        rows.append(
            (interface, "AB"[node_set], alpha[interface - 1], X_extra[local][2], expected[2])
        )

print("\nleft cell, column 0 (bottom base node at z = 0, top at z = h):")
print("interface  set  alpha_i   z (node)  z (Eq. 1)")
for interface, name, a, z_node, z_eq in sorted(rows):
    print(f"{interface:9d}  {name:>3}  {a:.5f}  {z_node:9.6f}  {z_eq:9.6f}")
print(
    f"largest |X - X_Eq.1| = {worst_position:.1e} mm, largest |s - alpha_i| = {worst_fraction:.1e}"
)
assert worst_position < 1e-14
assert worst_fraction < 1e-14

# %% [markdown]
# ## Neighbours share extra nodes
#
# Extra nodes belong to columns, not to cells. The two cells share the two columns of their
# common face. Both are refined at interface 4, so interface 4 has 6 extra nodes, not 8: the
# displacement stays continuous across the common face. (What happens when only one of two
# neighbours is refined is the subject of `06_border.py`.)

# %%
keys_at_4 = [
    key for key in structure.extra.index if enr.key_parts(key, n_interfaces)[1:] == (4, enr.SET_A)
]
print(f"\nextra nodes at interface 4: {len(keys_at_4)} (2 cells x 4 columns - 2 shared columns)")
assert len(keys_at_4) == 6

# %% [markdown]
# ## Set A and set B
#
# The paper describes each interface by two coinciding surfaces. A weak refinement activates the
# first surface (set A). A strong refinement activates the reserved copy (set B, the upper side
# of the future crack). Here set B is created only when needed. Its nodes start at the set-A
# positions, displacements and velocities, so the two surfaces coincide exactly.

# %%
structure.refine([(left, 4, InterfaceState.STRONG)])
pairs = 0
for key, local in structure.extra.index.items():
    global_bottom, interface, node_set = enr.key_parts(key, n_interfaces)
    if node_set == enr.SET_B:
        partner = structure.extra.index[
            enr.extra_key(global_bottom, interface, enr.SET_A, n_interfaces)
        ]
        for name in ("X", "u", "v"):
            values = structure.extra.vectors[name].array.reshape(-1, 3)
            assert np.array_equal(values[local], values[partner])
        pairs += 1
print(f"set-B nodes after the strong refinement of the left cell: {pairs}, each on its set-A twin")
assert pairs == 4

# %% [markdown]
# ## The picture: the strip seen from the side
#
# The front face (y = 0) of the two cells, plies to scale. Black squares are the base nodes,
# blue circles the set-A extra nodes, red crosses the set-B nodes (drawn a little to the right
# of their twins, with which they coincide). The dashed lines are the heights alpha_i h of
# Eq. (1): every extra node is on one. The left cell is refined at interfaces 2, 4 (weak, then
# strong) and 6; the right one at interface 4 only, and the two share the extra node of their
# common column at x = 1 mm.

# %%
h = laminate.thickness
X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)  # now with the set-B nodes
front_base = np.flatnonzero(np.isclose(structure.X_base[:, 1], 0.0))
fig, ax = plt.subplots(figsize=(8, 3.6))
draw_plies(ax, (0.0, 2.0), laminate.ply_fractions, h)
for i, a in enumerate(alpha, start=1):
    ax.axhline(a * h, color="0.4", ls="--", lw=0.6)
    ax.text(2.03, a * h, f"$\\alpha_{i}$ = {a:.3f}", va="center", fontsize=7)
for x in (0.0, 1.0, 2.0):
    ax.plot([x, x], [0.0, h], color="k", lw=1.2)  # the columns
ax.plot(*structure.X_base[front_base][:, [0, 2]].T, "ks", ms=7, label="base node")
drawn = {"A": 0, "B": 0}
for key, local in structure.extra.index.items():
    _, interface, node_set = enr.key_parts(key, n_interfaces)
    x, y, z = X_extra[local]
    if abs(y) > 1e-12:
        continue
    name = "AB"[node_set]
    assert abs(z - alpha[interface - 1] * h) < 1e-14  # on its dashed line: Eq. (1)
    ax.plot(
        x + (0.04 if name == "B" else 0.0),
        z,
        "o" if name == "A" else "x",
        color=SET_COLOURS[name],
        ms=7,
        mew=2,
        label=None if drawn[name] else f"extra node, set {name}",
    )
    drawn[name] += 1
# front face: the left cell's two columns have interfaces 2, 4 and 6 (the shared one's 4 is
# also the right cell's), the right cell's outer column has interface 4; set B only on the
# left cell's two columns
assert drawn == {"A": 3 + 3 + 1, "B": 2}
ax.set(xlabel="x (mm)", ylabel="z (mm)", xlim=(-0.1, 2.45), ylim=(-0.05, h + 0.05))
ax.set_title("two cells, extra nodes at the interface heights of Eq. (1)", fontsize=10)
ax.legend(loc="upper center", bbox_to_anchor=(0.45, -0.2), ncol=3, fontsize=8)
finish(fig, "01_strip_side_view")

# %%
print("01_extra_nodes: all checks passed")
