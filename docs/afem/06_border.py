# %% [markdown]
# # 6. The border of a refined region
#
# Refinement is local: some cells refine, their neighbours do not. An extra node on a column
# shared by a refined and an unrefined cell is a *border node*. This script shows why a border
# node may not move freely, how it is tied to its unrefined neighbour instead (like a hanging
# node), draws the border with and without that constraint, and checks that nothing is lost
# when the neighbour refines later.
#
# Run it from the repository root (serial, about 2 s):
#
#     .venv/bin/python docs/afem/06_border.py
#
# Units: N, mm, s, tonne (energies in mJ).

# %%
import tomllib

import matplotlib.pyplot as plt
import numpy as np
from afem_figures import finish
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.model.structure import cells_in_x_range
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

# %% [markdown]
# ## The problem
#
# Take two neighbouring cells. The left one is refined at interface 4 (the mid-plane), the
# right one is not. They share a column. Along that column the right cell's displacement is
# linear in the thickness, between its two base nodes. The left cell's displacement is linear
# from the bottom base node to the extra node, and from the extra node to the top base node. If
# the extra node left the straight line, the two cells would no longer meet along their common
# face: a gap on one side of the interface and an overlap on the other. The refined region
# would end in a hinge through part of the thickness, as if the plies were cracked there.
# Before the rule below existed, a four-point bending beam refined around mid-span came out
# about 20 % softer than the unrefined beam (`tests/test_border.py` now bounds it between the
# unrefined beam and the beam refined everywhere).
#
# ## The remedy
#
# A border node is *constrained*. Its *masters* are the nodes of its column that every cell
# around the column has: the two base nodes, plus any extra nodes of interfaces that all those
# cells have refined. The node sits on the straight line between the nearest master below and
# the nearest master above. For interface i between masters at fractions f_lo and f_hi:
#
# $$u = (1 - s)\, u_{\mathrm{lo}} + s\, u_{\mathrm{hi}}, \qquad
# s = \frac{\alpha_i - f_{\mathrm{lo}}}{f_{\mathrm{hi}} - f_{\mathrm{lo}}}$$
#
# Its force and its lumped mass are handed to the masters with the same weights (1 - s, s).
#
# One refinement of this rule: a node keeps the offset from that line that it has when its
# constraint is made, and moves with its masters from there (`border.record_offsets`). A new
# border node is placed by its refining cell on that cell's own field, which includes the
# enhanced thickness strain (a parabola through the thickness, zero at both faces,
# `solid_shell.enhanced_displacement`) that the straight line misses; on the straight line, a
# region grown one strip at a time, as behind a delamination front, jumped in strain energy at
# every step. The offset is fixed between refinements, so the node's velocity follows its
# masters' exactly and the mass, the momentum and the energy balance stay exact. Here the
# structure is at rest when it refines: the offsets are zero.

# %%
CONFIG = """
[model]
kind = "adaptive"

[mesh]
length = 4.0
width = 1.0
nx = 4
ny = 1

[materials.ply]
E1 = 100000.0
E2 = 10000.0
G12 = 5000.0
G23 = 4000.0
nu12 = 0.25
nu23 = 0.25
rho = 1.6e-9

[laminate]
material = "ply"
ply_thickness = 0.25
angles = [0, 90, 0, 90, 90, 0, 90, 0]

[interfaces]
refine = [4]
delaminate = [2]

[cohesive]
K_n = 1.0e5
K_s = 1.0e5
N = 20.0
S = 40.0
GIc = 0.4
GIIc = 1.0
law = "bk"
exponent = 2.0

[[clamp]]
face = "x0"

[solver]
end_time = 1.0e-5

[output]
interval = 1.0e-6
displacement_face = "x0"
reaction_face = "x0"
component = "z"
[stabilisation]
# the new nodes stay where the refinement places them, which this page follows (a run's
# default then puts the refined cells' nodes in equilibrium: adaptivity/equilibration.py)
equilibrate = false
"""

assert MPI.COMM_WORLD.size == 1, "run this script in serial"
structure = build_structure(parse_config(tomllib.loads(CONFIG), source="06_border"))
n_interfaces = structure.laminate.n_plies - 1

# %% [markdown]
# ## Refine the left half
#
# Four cells of 1 x 1 mm along x. The two left cells refine weakly at interface 4. The columns
# at x = 0 and x = 1 mm belong to refined cells only: their extra nodes are free. The columns at
# x = 2 mm are shared with the unrefined third cell: their extra nodes are border nodes.
# `Structure.border` lists the constrained degrees of freedom with their masters and weights.

# %%
structure.refine([(int(c), 4, InterfaceState.WEAK) for c in cells_in_x_range(structure, 0.0, 2.0)])
border = structure.border
n_base_dofs = 3 * structure.n_base
X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)


def describe(flat_dof):
    """The node a combined flat DOF index belongs to, and its height."""
    node = flat_dof // 3
    if node < structure.n_base:
        return f"base node {node} at z = {structure.X_base[node, 2]:.2f}"
    return f"extra node {node - structure.n_base} at z = {X_extra[node - structure.n_base, 2]:.2f}"


print("constrained DOFs (x components; y and z are alike):")
for dof, masters, weights in zip(border.dofs, border.masters, border.weights, strict=True):
    if dof % 3 == 0:
        node = (dof - n_base_dofs) // 3
        x, y = np.abs(X_extra[node, :2])
        print(f"  extra node {node} at (x, y) = ({x:.0f}, {y:.0f}):")
        for master, weight in zip(masters, weights, strict=True):
            print(f"      {weight:.2f} x {describe(master)}")
constrained_nodes = np.unique((border.dofs - n_base_dofs) // 3)
assert np.allclose(X_extra[constrained_nodes, 0], 2.0)
assert len(border.dofs) == 2 * 3  # two border nodes, three components each
assert np.all(border.weights == 0.5)  # interface 4 is the mid-plane
assert np.all(border.masters < n_base_dofs)  # both masters are base nodes

# %% [markdown]
# ## The two sides agree along the shared column
#
# We give every base node and every extra node a random displacement, then let the border
# nodes follow their masters (`Structure.follow_border`; the explicit solver does this after
# every step). At the border columns, the refined cell's value at the interface height (its
# extra node) must equal the unrefined cell's value there (the mean of its two base nodes,
# since alpha_4 = 1/2). Free extra nodes keep their random offset from that line.

# %%
rng = np.random.default_rng(5)
u_base = structure.base.u.x.array.reshape(-1, 3)
u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
u_base[:] = 1e-4 * rng.standard_normal(u_base.shape)
u_extra[:] = 1e-4 * rng.standard_normal(u_extra.shape)
u_free_base, u_free_extra = u_base.copy(), u_extra.copy()  # for the picture below
structure.follow_border()

print("\ncolumn (x, y)  extra node u_x   mean of base nodes u_x   difference")
by_position = sorted(
    structure.extra.index.items(), key=lambda item: tuple(np.round(X_extra[item[1], :2], 6))
)
for key, local in by_position:
    global_bottom, _, _ = enr.key_parts(key, n_interfaces)
    bottom = structure.extra.local_base_node(global_bottom)
    top = structure.columns.top_of[bottom]
    on_line = 0.5 * (u_base[bottom] + u_base[top])
    difference = np.abs(u_extra[local] - on_line).max()
    x, y = np.abs(X_extra[local, :2])  # abs: print 0.0, not -0.0 from round-off
    print(
        f"  ({x:.0f}, {y:.0f})       {u_extra[local, 0]:+.6e}    {on_line[0]:+.6e}"
        f"            {difference:.1e}"
    )
    if local in constrained_nodes:
        assert difference < 1e-15
    else:
        assert difference > 1e-6

# %% [markdown]
# ### The picture: the border column with and without the constraint
#
# The front face (y = 0) of the four cells, deformed by the random field above and magnified
# 2000 times. Each cell is drawn through its own nodes: the refined cells (blue) through their
# extra nodes, the unrefined ones (grey) straight from bottom to top. Left, the field as it
# was set, with every extra node free: at x = 2 mm the refined cell's edge has a kink that the
# unrefined cell's straight edge does not follow, so the two overlap on one side of the
# interface and leave a gap on the other. Right, after `follow_border`: the border node sits
# on the straight edge of its unrefined neighbour, and the two cells meet again. The free
# extra nodes (x = 0 and 1 mm) keep their kinks: inside the refined region the strain may jump.

# %%
MAGNIFY = 2000.0


def front_face_outline(cell, u_base_values, u_extra_values):
    """Deformed (x, z) outline of a cell's front face: bottom-left, [extra], top-left,
    top-right, [extra], bottom-right, as drawn (u magnified)."""
    X_all = np.vstack([structure.X_base, X_extra])
    u_all = np.vstack([u_base_values, u_extra_values])
    refined = structure.interface_state[cell][4 - 1] != InterfaceState.NONE
    columns = []
    for corner in range(4):
        bottom = structure.bottom_local[cell][corner]
        if not np.isclose(structure.X_base[bottom, 1], 0.0):
            continue
        nodes = [bottom]
        if refined:
            key = enr.extra_key(structure.bottom_global[cell][corner], 4, enr.SET_A, n_interfaces)
            nodes.append(structure.n_base + structure.extra.index[key])
        nodes.append(structure.top_local[cell][corner])
        columns.append(np.array(nodes))
    columns.sort(key=lambda nodes: X_all[nodes[0], 0])
    outline = np.concatenate([columns[0], columns[1][::-1], columns[0][:1]])
    deformed = X_all[outline] + MAGNIFY * u_all[outline]
    return deformed[:, [0, 2]], refined


fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
for ax, (title, u_b, u_e) in zip(
    axes,
    (
        ("extra nodes free: gap and overlap at x = 2 mm", u_free_base, u_free_extra),
        ("border node constrained (follow_border)", u_base, u_extra),
    ),
    strict=True,
):
    for cell in range(structure.X_base[structure.bottom_local].shape[0]):
        outline, refined = front_face_outline(cell, u_b, u_e)
        colour = "tab:blue" if refined else "0.5"
        ax.fill(*outline.T, color=colour, alpha=0.25, lw=0)
        ax.plot(*outline.T, color=colour, lw=1.5, marker="o", ms=3)
    ax.axvline(2.0, color="tab:red", ls=":", lw=1)
    ax.set(xlabel="x (mm)", title=title)
axes[0].set_ylabel("z (mm)")
finish(fig, "06_border_constraint")

# %% [markdown]
# ## Forces and masses go to the masters
#
# The solver never integrates a constrained degree of freedom: its force and its mass are
# handed to the masters, and its motion is read back from them. After `internal_force`, a
# border node carries no force; in the masses the solver divides by, it carries none either.
# The total mass does not change.
#
# Handing the force over with the interpolation weights is not a guess: it makes the nodal
# forces the gradient of the energy of the constrained structure. We check that with a central
# difference of the energy along a random direction that respects the constraints.

# %%
structure.internal_force()
f_base = structure.f_base.array.copy()
f_extra = structure.f_extra.array.copy()
extra_dofs = border.dofs - n_base_dofs
print(f"\nforce on border DOFs: {f_extra[extra_dofs]}")
print(f"solver mass of border DOFs: {structure.extra_block.mass[extra_dofs]}")
print(f"assembled mass of those nodes: {structure.mass_extra.array[extra_dofs][::3]} tonne")
assert np.all(f_extra[extra_dofs] == 0.0)
assert np.all(structure.extra_block.mass[extra_dofs] == 0.0)
assert np.all(structure.mass_extra.array[extra_dofs] > 0.0)
mass = structure.total_mass()
expected_mass = structure.laminate.areal_mass() * 4.0 * 1.0
print(f"total mass {mass:.6e} tonne, rho t A = {expected_mass:.6e} tonne")
assert abs(mass - expected_mass) < 1e-13 * expected_mass

direction_base = rng.standard_normal(f_base.shape)
direction_extra = rng.standard_normal(f_extra.shape)
direction_extra[extra_dofs] = 0.0  # border DOFs follow; they are not free to vary
u0_base, u0_extra = structure.base.u.x.array.copy(), structure.extra.vectors["u"].array.copy()
h = 1e-8
energy = []
for sign in (1.0, -1.0):
    structure.base.u.x.array[:] = u0_base + sign * h * direction_base
    structure.extra.vectors["u"].array[:] = u0_extra + sign * h * direction_extra
    structure.follow_border()
    structure.internal_force()
    energy.append(sum(structure.internal_forces.energies()))
structure.base.u.x.array[:], structure.extra.vectors["u"].array[:] = u0_base, u0_extra
structure.follow_border()
slope = (energy[0] - energy[1]) / (2 * h)
predicted = f_base @ direction_base + f_extra @ direction_extra
print(f"dW/du . d = {slope:.8e}, f . d = {predicted:.8e}")
assert abs(slope - predicted) < 1e-6 * abs(predicted)

# %% [markdown]
# ## When the neighbour refines, the node is freed
#
# Now the third cell refines too. Every cell around the x = 2 mm columns is refined, so their
# extra nodes become free, and the border moves to x = 3 mm. The freed node already sits where
# the newly refined cell puts it, so the compatible strain field does not change. What does
# change, a little, is the enhanced thickness strain of the newly refined cell: the cell
# condensed one set of parameters, its two subelements condense one set each, so at the same
# nodal displacements the strain energy moves by about one part in ten thousand. The structure
# books that change as refinement energy (the energy balance stays closed). The lumped masses
# move too; with the structure at rest no kinetic energy is booked.

# %%
structure.internal_force()
before = sum(structure.internal_forces.energies())
structure.refine([(int(c), 4, InterfaceState.WEAK) for c in cells_in_x_range(structure, 2.0, 3.0)])
structure.internal_force()
after = sum(structure.internal_forces.energies())
X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
now_constrained = np.unique((structure.border.dofs - n_base_dofs) // 3)
print(f"\nborder columns now at x = {np.unique(X_extra[now_constrained, 0])} mm")
print(f"strain energy before {before:.10e} mJ, after {after:.10e} mJ")
print(f"booked refinement energy {structure.refinement_energy:.1e} mJ")
assert np.allclose(X_extra[now_constrained, 0], 3.0)
assert abs(after - before) < 2e-3 * before
assert abs(structure.refinement_energy - (after - before)) < 1e-9 * before

# %% [markdown]
# ## At the front of a strong region the crack stays closed
#
# The same rule holds for the upper side of a delamination. A set-B node is free only when
# every cell around its column is strong at that interface. Otherwise it follows its set-A twin
# with weight 1: the crack is closed at the front of the strong region, and it opens only where
# the cohesive elements on both sides let it. Here the first cell turns strong at interface 2
# and the second only weak.

# %%
first, second = cells_in_x_range(structure, 0.0, 1.0)[0], cells_in_x_range(structure, 1.0, 2.0)[0]
structure.refine([(int(first), 2, InterfaceState.STRONG), (int(second), 2, InterfaceState.WEAK)])
border = structure.border
for key, local in structure.extra.index.items():
    _, interface, node_set = enr.key_parts(key, n_interfaces)
    if interface == 2 and node_set == enr.SET_B:
        x = structure.extra.vectors["X"].array.reshape(-1, 3)[local, 0]
        rows = np.flatnonzero(border.dofs // 3 == structure.n_base + local)
        if x < 0.5:
            assert len(rows) == 0  # the beam's end: only the strong cell is around
            print("set-B node at x = 0: free")
        else:
            assert len(rows) == 3 and np.all(border.weights[rows] == [1.0, 0.0])
            print(f"set-B node at x = {x:.0f}: follows its set-A twin (weights 1, 0)")

# %%
print("06_border: all checks passed")
