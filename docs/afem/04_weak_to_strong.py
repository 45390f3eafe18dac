# %% [markdown]
# # 4. From weak to strong refinement
#
# A weak refinement lets the strain jump at a ply interface; a strong refinement lets the
# displacement jump there (a delamination). Neither may change the state of the structure at the
# moment it happens: the displacement field, the velocity field, the mass and the momentum stay
# the same, and a new cohesive element starts closed, with zero traction. This script refines a
# region of a beam weakly, then strongly, checks all of that, and draws one column through the
# thickness in the three states.
#
# Run it from the repository root (serial, about 2 s):
#
#     .venv/bin/python docs/afem/04_weak_to_strong.py
#
# Units: N, mm, s, tonne (energies in mJ = N mm, momentum in tonne mm/s).

# %%
import tomllib

import matplotlib.pyplot as plt
import numpy as np
from afem_figures import finish
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.materials.cohesive import cohesive_element_force
from fenics_adaptive.materials.laminate import element_shear_factors
from fenics_adaptive.model.structure import cells_in_x_range
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

# %% [markdown]
# ## The model
#
# The beam of the paper's TCB example, shortened: 10 x 0.5 mm, eight 0-degree plies of
# 0.256 mm, 20 cells along x. Interface 4 may refine weakly; interfaces 2 and 6 may also
# delaminate.

# %%
CONFIG = """
[model]
kind = "adaptive"

[mesh]
length = 10.0
width = 0.5
nx = 20
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
ply_thickness = 0.256
angles = [0, 0, 0, 0, 0, 0, 0, 0]

[interfaces]
refine = [4]
delaminate = [2, 6]

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
structure = build_structure(parse_config(tomllib.loads(CONFIG), source="04_weak_to_strong"))
n_interfaces = structure.laminate.n_plies - 1
alpha = structure.laminate.interface_fractions

# %% [markdown]
# ## A moving, deformed beam
#
# We put a displacement field and a velocity field on the base nodes by hand (a state in the
# middle of a dynamic run would do as well). The displacement stretches the laminate through
# its thickness and shears it, u_z = e z and u_x = g z: the ply interfaces carry a normal stress
# and a shear stress, which matters below. The velocity is not uniform (a spin and a stretch).
# Then we record what must not change.

# %%
X = structure.X_base
stretch, shear = 2e-4, 2e-4  # e and g, dimensionless
u_base = structure.base.u.x.array.reshape(-1, 3)
v_base = structure.v_base.array.reshape(-1, 3)
u_base[:, 0] = shear * X[:, 2]
u_base[:, 2] = stretch * X[:, 2]
v_base[:, 0] = -5.0 * X[:, 2]  # mm/s
v_base[:, 2] = 10.0 * X[:, 0]


def snapshot(structure):
    """What the state is made of: strain energies, mass, momentum, kinetic energy."""
    structure.internal_force()
    solid, cohesive = structure.internal_forces.energies()
    return {
        "solid": solid,
        "cohesive": cohesive,
        "mass": structure.total_mass(),
        "momentum": structure.momentum(),
        "kinetic": structure.kinetic_energy(),
    }


def report(title, now, before):
    print(f"\n{title}")
    print(f"  strain energy of the solids {now['solid']:.9e} mJ (before {before['solid']:.9e})")
    print(f"  cohesive energy             {now['cohesive']:.1e} mJ")
    print(f"  total mass                  {now['mass']:.9e} tonne")
    print(f"  momentum                    {now['momentum']} tonne mm/s")
    print(f"  kinetic energy              {now['kinetic']:.9e} mJ (before {before['kinetic']:.9e})")


def column_profile(structure, x, y):
    """Heights z (mm), u and v (mm, mm/s) of the active nodes of the column at (x, y), bottom
    to top, and each node's set ("base", "A" or "B")."""
    X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
    u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
    v_extra = structure.extra.vectors["v"].array.reshape(-1, 3)
    rows = []
    base = np.flatnonzero(np.isclose(X[:, 0], x) & np.isclose(X[:, 1], y))
    rows += [(X[n, 2], u_base[n], v_base[n], "base") for n in base]
    for key, local in structure.extra.index.items():
        if np.allclose(X_extra[local, :2], (x, y)):
            name = "AB"[enr.key_parts(key, n_interfaces)[2]]
            rows.append((X_extra[local, 2], u_extra[local].copy(), v_extra[local].copy(), name))
    rows.sort(key=lambda row: (row[0], row[3]))
    return rows


COLUMN = (4.5, 0.0)  # mm: a column inside the refined region
profiles = {"before refinement": column_profile(structure, *COLUMN)}
start = snapshot(structure)

# %% [markdown]
# ## Weak refinement: new nodes on the old field
#
# The cells between x = 2.5 and 6.5 mm refine weakly at interfaces 2, 4 and 6. Each new extra
# node takes its reference position from Eq. (1) and its displacement and velocity by the same
# interpolation between the active nodes below and above it. Along a vertical edge the field of
# an unrefined cell is linear in the thickness, so the node lands exactly on the old field:
#
# $$u_{\mathrm{extra}} = u_{\mathrm{bottom}}
# + \alpha_i \left(u_{\mathrm{top}} - u_{\mathrm{bottom}}\right)
# \qquad \text{(likewise } v\text{)}$$
#
# This holds for any nodal field, not only for the simple one chosen above: whatever the base
# nodes carry, the compatible field of a cell is linear along each of its columns. The cell's
# strain has one more part, its enhanced thickness strain (linear in the thickness, zero mean;
# see Element in the README), which bending makes nonzero and this uniform state does not. The
# new node takes it too: its displacement integrated along the edge, a parabola through the
# thickness that vanishes at both faces (`solid_shell.enhanced_displacement`). Every subelement
# then reproduces the part of the old strain it covers, and the strain energy of a bent cell
# stays (`tests/test_enrichment.py` checks it); on the straight line alone it would jump by
# about half a per cent. The mass (the subelements' masses replace the cell's) and the momentum
# (the lumped masses move with the same interpolation weights) do not change; the strain does
# not either.

# %%
region = cells_in_x_range(structure, 2.5, 6.5)
print(f"refining {len(region)} cells at interfaces 2, 4, 6 (weak)")
structure.refine([(int(c), i, InterfaceState.WEAK) for c in region for i in (2, 4, 6)])


def largest_deviation_from_old_field(structure, name, base_values):
    """Largest |value - interpolated old value| over all extra nodes, for u or v."""
    values = structure.extra.vectors[name].array.reshape(-1, 3)
    worst = 0.0
    for key, local in structure.extra.index.items():
        global_bottom, interface, _ = enr.key_parts(key, n_interfaces)
        bottom = structure.extra.local_base_node(global_bottom)
        top = structure.columns.top_of[bottom]
        old = base_values[bottom] + alpha[interface - 1] * (base_values[top] - base_values[bottom])
        worst = max(worst, np.abs(values[local] - old).max())
    return worst


profiles["after weak refinement"] = column_profile(structure, *COLUMN)
du = largest_deviation_from_old_field(structure, "u", u_base)
dv = largest_deviation_from_old_field(structure, "v", v_base)
weak = snapshot(structure)
report("after the weak refinement", weak, start)
print(f"  extra nodes off the old field: u by {du:.1e} mm, v by {dv:.1e} mm/s")
assert du < 1e-15 and dv < 1e-13
assert abs(weak["mass"] - start["mass"]) < 1e-14 * start["mass"]
momentum_scale = np.linalg.norm(start["momentum"])
assert np.abs(weak["momentum"] - start["momentum"]).max() < 1e-13 * momentum_scale

# %% [markdown]
# Two energies may change. The kinetic energy: the same velocities now multiply redistributed
# lumped masses. And the transverse shear energy, by design. An element's transverse shear
# strain is constant through its thickness, so each (sub)element's shear moduli carry the
# laminate's shear correction factor over its own span of plies
# (`materials.laminate.element_shear_factors`: the span's share of the laminate's exact shear
# flow, stored with the exact complementary energy). The eight-ply cell has $k = 5/6$, a
# homogeneous section's; each two-ply subelement has the factor of where it sits in that flow
# (nearer 1 in the middle, where the flow hardly varies). Within an element each ply takes its
# own share of the flow (`materials.laminate.ply_shear_factors`), which add up to that factor:
# a strain constant through the element stores what the factor says. The uniform shear $g$ of
# this state
# then stores $	frac12 g^2 G_{13} A \sum_i k_i h_i$ instead of $	frac12 g^2 G_{13} A\, k\, h$
# over the refined area $A$: more, because the subelements may follow the flow the cell had to
# average (by Cauchy-Schwarz, $\sum_i k_i h_i \ge k h$ for any split). We compute the change by
# hand. With `[model] shear_correction = false` every factor is 1 and the strain energy stays
# to round-off. The structure books both changes as `refinement_energy`, so the energy balance
# of a run still closes.

# %%
laminate = structure.laminate
G13 = laminate.plies[0].stiffness()[4, 4]  # MPa: C_55 of the 0-degree plies
h_ply = laminate.thickness / laminate.n_plies  # mm
area = len(region) * (10.0 / 20) * 0.5  # mm^2: refined cells of 0.5 x 0.5 mm
k_cell = element_shear_factors(laminate, 0, 8)[0]
k_spans = [element_shear_factors(laminate, first, first + 2)[0] for first in (0, 2, 4, 6)]
expected = 0.5 * shear**2 * G13 * area * h_ply * (2 * sum(k_spans) - 8 * k_cell)  # mJ
print(f"  shear factors k_xz: cell {k_cell:.4f}, subelements {np.round(k_spans, 4)}")
change = weak["solid"] - start["solid"]
print(f"  strain energy change        {change:.6e} mJ ({expected:.6e} by hand)")
print(f"  booked refinement energy    {structure.refinement_energy:.6e} mJ")
assert abs(weak["solid"] - start["solid"] - expected) < 1e-9 * start["solid"]
kinetic_change = weak["kinetic"] - start["kinetic"]
booked = kinetic_change + weak["solid"] - start["solid"]
assert abs(booked - structure.refinement_energy) < 1e-12 * start["solid"]

# %% [markdown]
# ## Strong refinement: unzip, closed
#
# The same cells now turn strong at interfaces 2 and 6. Each interface gets its set-B nodes,
# copied from set A (position, displacement, velocity), and a cohesive element between the two
# sets. The twins move together, so this time even the kinetic energy stays: set B takes over
# part of set A's lumped mass, at the same velocity. The subelements keep their spans (the
# interfaces were weak already), hence their shear factors: the strain energy stays too. Before
# this step we record the internal force on every set-A node.

# %%
f_extra_before = structure.f_extra.array.reshape(-1, 3).copy()
index_before = dict(structure.extra.index)
structure.refine([(int(c), i, InterfaceState.STRONG) for c in region for i in (2, 6)])
strong = snapshot(structure)
report("after the strong refinement", strong, start)

u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
v_extra = structure.extra.vectors["v"].array.reshape(-1, 3)
pairs = []
for key, local in structure.extra.index.items():
    global_bottom, interface, node_set = enr.key_parts(key, n_interfaces)
    if node_set == enr.SET_B:
        twin = enr.extra_key(global_bottom, interface, enr.SET_A, n_interfaces)
        pairs.append((structure.extra.index[twin], local, index_before[twin]))
a_nodes, b_nodes, a_before = (np.array(column) for column in zip(*pairs, strict=True))
assert np.array_equal(u_extra[a_nodes], u_extra[b_nodes])
assert np.array_equal(v_extra[a_nodes], v_extra[b_nodes])
assert abs(strong["solid"] - weak["solid"]) < 1e-12 * weak["solid"]
assert abs(strong["kinetic"] - weak["kinetic"]) < 1e-12 * weak["kinetic"]
assert np.abs(strong["momentum"] - start["momentum"]).max() < 1e-13 * momentum_scale
print(f"  {len(pairs)} node pairs, each with the same u and v on both sides")

# %% [markdown]
# ### The new cohesive elements are closed and carry nothing
#
# The opening is the jump u_B - u_A, zero for every element. We evaluate each cohesive element
# on its own: zero force, zero stored energy, no damage.

# %%
X_all = np.vstack([structure.X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])
u_all = np.vstack([u_base, u_extra])
largest_traction_force = 0.0
for nodes in structure.cohesive.nodes:
    f_element = np.zeros((8, 3))
    damage = np.zeros(4)
    energy, _ = cohesive_element_force(
        X_all[nodes], u_all[nodes], structure.cohesive.params, damage, f_element
    )
    assert energy == 0.0 and not damage.any()
    largest_traction_force = max(largest_traction_force, np.abs(f_element).max())
print(
    f"  {len(structure.cohesive)} cohesive elements, largest nodal force {largest_traction_force}"
)
assert len(structure.cohesive) == 2 * len(region)
assert largest_traction_force == 0.0 and strong["cohesive"] == 0.0

# %% [markdown]
# ### Only where the forces land changes
#
# Before, a set-A node collected the force of the subelement below and of the subelement above
# the interface. Now the subelement above acts on the set-B twin. The sum of the two is the old
# force, to round-off. But each side alone now carries the whole interface stress: in our
# uniform state, on a node away from the edges of the region, f_A = +(k_b sigma_xz, 0,
# sigma_zz) A and f_B = -(k_a sigma_xz, 0, sigma_zz) A, with A the node's share of the
# interface area (0.125 mm^2 here: a quarter of each of the two 0.5 x 0.5 mm cells around it)
# and k_b, k_a the shear factors of the subelements below and above. (Their difference is the x
# force the node carried before the split: the uniform strain is not in equilibrium at a
# change of shear factor, as it would not be at a change of shear modulus.) The two faces
# would accelerate apart at once, although nothing has opened yet. That jump is the subject of
# `05_stabilisation.py`. (The y components come from the in-plane stress sigma_yy, which the
# Poisson effect creates, acting on the free side face y = 0 of the beam. They are not an
# interface stress; the split shares them between the two sides.)

# %%
f_extra = structure.f_extra.array.reshape(-1, 3)
split_sum_error = np.abs(f_extra[a_nodes] + f_extra[b_nodes] - f_extra_before[a_before]).max()
print(f"  |f_A + f_B - f_before| at most {split_sum_error:.1e} N")
assert split_sum_error < 1e-12 * np.abs(f_extra[a_nodes]).max()

C = structure.laminate.plies[0].stiffness()  # Voigt order xx, yy, zz, yz, xz, xy
strain = np.array([0.0, 0.0, stretch, 0.0, shear, 0.0])
sigma = C @ strain
traction = np.array([sigma[4], 0.0, sigma[2]])  # MPa, on a plane of normal z
k_below, k_above = k_spans[0], k_spans[1]  # the subelements either side of interface 2
X_extra = structure.extra.vectors["X"].array.reshape(-1, 3)
middle = np.flatnonzero(np.isclose(X_extra[a_nodes, 0], 4.5) & np.isclose(X_extra[a_nodes, 1], 0.0))
pair = middle[0]
A, B = a_nodes[pair], b_nodes[pair]
node_area = 2 * 0.25 * (0.5 * 0.5)
print(f"  pair at x = 4.5 mm: sigma_zz = {sigma[2]:.3f} MPa, sigma_xz = {sigma[4]:.3f} MPa")
print(f"    f on A before the split {f_extra_before[a_before[pair]]} N")
print(f"    f on A after            {f_extra[A]} N")
print(f"    f on B after            {f_extra[B]} N")
print(f"    traction x node area    {traction * node_area} N (x: times k_b, k_a)")
expected_a = np.array([k_below * traction[0], traction[2]]) * node_area
expected_b = -np.array([k_above * traction[0], traction[2]]) * node_area
assert np.allclose(f_extra[A, [0, 2]], expected_a, rtol=1e-10)
assert np.allclose(f_extra[B, [0, 2]], expected_b, rtol=1e-10)

# %% [markdown]
# ## The picture: one column before and after
#
# The column at x = 4.5 mm, y = 0 through the thickness, in the three states: its active nodes
# and the displacement and velocity they carry (x and z components). The weak refinement adds
# nodes at interfaces 2, 4 and 6 on the straight line of the old field; the strong one adds the
# set-B twins at 2 and 6 on top of set A. The lines do not move (here u_x and u_z happen to
# coincide: shear and stretch are both 2e-4). The right panel shows the z force of interface 6
# at this column. Before the split the node sits in a uniform stress field and its force is
# zero: the subelements below and above cancel. After it, A and B each carry the whole
# interface stress, with opposite signs; their sum is still the old, zero force.

# %%
profiles["after strong refinement"] = column_profile(structure, *COLUMN)
styles = {
    "before refinement": ("k", "s", 9),
    "after weak refinement": ("tab:blue", "o", 6),
    "after strong refinement": ("tab:red", "x", 7),
}
fig, axes = plt.subplots(1, 3, figsize=(11, 4), gridspec_kw={"width_ratios": [1, 1, 1.1]})
for state, rows in profiles.items():
    colour, marker, size = styles[state]
    z = np.array([row[0] for row in rows])
    for ax, field in zip(axes[:2], (1, 2), strict=True):
        values = np.array([row[field] for row in rows])
        for component, fill in ((0, "full"), (2, "none")):
            ax.plot(
                values[:, component],
                z,
                marker=marker,
                color=colour,
                ms=size,
                ls="-",
                lw=0.8,
                fillstyle=fill,
                label=f"{state}, {'xyz'[component]}",
            )
    assert (
        len(rows)
        == {"before refinement": 2, "after weak refinement": 5, "after strong refinement": 7}[state]
    )
for ax, title in zip(axes[:2], ("displacement u (mm)", "velocity v (mm/s)"), strict=True):
    for fraction in alpha[[1, 3, 5]]:
        ax.axhline(fraction * structure.laminate.thickness, color="0.8", lw=0.6, zorder=0)
    ax.set(xlabel=title, ylabel="z (mm)")
axes[0].legend(fontsize=6, loc="lower right")
# the force on the pair at interface 6 of this column (z components)
pair6 = [p for p in range(len(a_nodes)) if np.allclose(X_extra[a_nodes[p]], (*COLUMN, 6 * 0.256))]
assert len(pair6) == 1
A6, B6, before6 = a_nodes[pair6[0]], b_nodes[pair6[0]], a_before[pair6[0]]
bars = {
    "A before": f_extra_before[before6, 2],
    "A after": f_extra[A6, 2],
    "B after": f_extra[B6, 2],
    "A + B after": f_extra[A6, 2] + f_extra[B6, 2],
}
axes[2].bar(list(bars), list(bars.values()), color=["k", "tab:blue", "tab:red", "0.6"])
axes[2].axhline(0.0, color="k", lw=0.6)
axes[2].set(ylabel="internal force f_z (N)", title="interface 6, x = 4.5 mm")
axes[2].tick_params(axis="x", labelsize=8)
assert abs(bars["A + B after"] - bars["A before"]) < 1e-12 * abs(bars["A after"])
finish(fig, "04_column_fields_and_force_split")

# %%
print("04_weak_to_strong: all checks passed")
