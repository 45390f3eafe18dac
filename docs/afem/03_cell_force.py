# %% [markdown]
# # 3. The internal force of one refined cell: f = f_lam - f_coh
#
# The internal force of a refined cell is assembled from its subelements and its cohesive
# elements (paper, Eqs. (3)-(7)):
#
# $$f = f^{\mathrm{lam}} - f^{\mathrm{coh}}, \qquad
# f^{\mathrm{lam}} = \sum_i P^{\mathrm{sublam},i\,T} f^{\mathrm{sublam},i}, \qquad
# f^{\mathrm{coh}} = \sum_j P^{\mathrm{coh},j\,T} f^{\mathrm{coh},j}$$
#
# This script computes that force twice for the cell of Figure 2 (seven plies, weak at
# interface 2, strong at interface 4). Once by the package (`Structure.internal_force`, numba
# loops over index lists), once here by the formula itself, with dense 0/1 matrices P and the
# element kernels called one by one. The two must agree to round-off. It then draws the three
# forces as arrows and checks the physics: the force is the gradient of the stored energy, it
# has no resultant, and a rigid translation produces none.
#
# Run it from the repository root (serial, about 2 s):
#
#     .venv/bin/python docs/afem/03_cell_force.py
#
# Units: N, mm, s, tonne (forces in N, energies in mJ = N mm).

# %%
import tomllib

import matplotlib.pyplot as plt
import numpy as np
from afem_figures import SET_COLOURS, TUTORIAL_DIR, draw_plies, finish
from mpi4py import MPI

from fenics_adaptive.adaptivity import enrichment as enr
from fenics_adaptive.element.subelement import solid_shell_force
from fenics_adaptive.materials.cohesive import cohesive_element_force
from fenics_adaptive.settings.config import parse_config
from fenics_adaptive.settings.kinds import InterfaceState
from fenics_adaptive.simulation import build_structure

# %% [markdown]
# ## One cell, refined as in Figure 2
#
# The mesh has a single cell, so the force of "the structure" is the force of that cell. No
# other cell adds to its nodes, and there is no border of a refined region (see `06_border.py`).

# %%
data = tomllib.loads((TUTORIAL_DIR / "seven_plies.toml").read_text())  # Figure 2
# the new nodes stay where the refinement places them, whose forces this page sums (a run's
# default then puts the refined cells' nodes in equilibrium: adaptivity/equilibration.py)
data["stabilisation"] = {"equilibrate": False}

assert MPI.COMM_WORLD.size == 1, "run this script in serial"
config = parse_config(data, source="03_cell_force")
structure = build_structure(config)
cell = 0

# %% [markdown]
# ## A deformed state
#
# The base nodes get a smooth field: bending about y (u_x = -kappa x z, u_z = kappa x^2 / 2)
# plus a small twist (u_z = 2e-5 x y), small enough for small-strain theory. Refining then
# interpolates the extra nodes from it (see `04_weak_to_strong.py`). On top of that, the
# interface-2 nodes move by a small random amount (a kink: a strain discontinuity, which only a
# weakly refined cell can carry), and the upper face of interface 4 (set B) opens by 2e-5 mm
# and slides by 1e-5 mm. Both openings are far
# below the cohesive onset N / K_n = 2e-4 mm, so the interface stays elastic.

# %%
X_base = structure.X_base
kappa = 1e-4  # 1/mm
x, z = X_base[:, 0], X_base[:, 2] - 0.5 * structure.laminate.thickness
u_base = structure.base.u.x.array.reshape(-1, 3)
u_base[:, 0] = -kappa * x * z
u_base[:, 2] = 0.5 * kappa * x**2 + 2e-5 * x * X_base[:, 1]
structure.refine([(cell, 2, InterfaceState.WEAK), (cell, 4, InterfaceState.STRONG)])

n_interfaces = structure.laminate.n_plies - 1
u_extra = structure.extra.vectors["u"].array.reshape(-1, 3)
rng = np.random.default_rng(7)
opening = np.array([1e-5, 0.0, 2e-5])  # mm: slide along x, open along z
for key, local in structure.extra.index.items():
    _, interface, node_set = enr.key_parts(key, n_interfaces)
    if interface == 2:
        u_extra[local] += 1e-5 * rng.standard_normal(3)
    if interface == 4 and node_set == enr.SET_B:
        u_extra[local] += opening

# %% [markdown]
# ## Path 1: the package
#
# `internal_force` fills `f_base` and `f_extra`: the solid elements' loop (unrefined cells
# whole, none here, and the subelements), the cohesive loop (with the minus sign), then the
# border transfer (none here).

# %%
structure.internal_force()
f_package = np.vstack(
    [structure.f_base.array.reshape(-1, 3), structure.f_extra.array.reshape(-1, 3)]
)

# %% [markdown]
# ## Path 2: the formula, with explicit matrices
#
# The cell's node vector lists the base nodes, then the extra nodes. For subelement i we build
# P_i (8 rows, one 1 per row) from its index list, gather X_i = P_i X and u_i = P_i u, call the
# layered solid-shell kernel with the rule of that subelement's plies, and scatter P_i^T f_i.
# Likewise for the cohesive element. Nothing is shared with path 1 except the two element
# kernels, the index lists and the integration rules: every span of plies takes its rule from
# the structure's one table (`structure.rule_table`, which also gives a one-ply subelement at
# least two points through its thickness, whatever `points_per_ply` says), not from a copy
# made here.

# %%
n_nodes = structure.n_base + structure.extra.n_local
X_all = np.vstack([X_base, structure.extra.vectors["X"].array.reshape(-1, 3)])


def u_all():
    return np.vstack([u_base, u_extra])


columns = enr.CellColumns(
    structure.bottom_local[cell], structure.top_local[cell], structure.bottom_global[cell]
)
state = structure.interface_state[cell]
n_plies = structure.laminate.n_plies
fractions = structure.laminate.ply_fractions


def projection(nodes):
    P = np.zeros((8, n_nodes))
    P[np.arange(8), nodes] = 1.0
    return P


def formula_force(u):
    """f_lam - f_coh of the cell, and the two parts, by Eqs. (3)-(7)."""
    f_lam = np.zeros((n_nodes, 3))
    for sub in enr.subelements(state):
        nodes = enr.subelement_nodes(
            state, sub, columns, n_plies, structure.extra.index, structure.n_base
        )
        P = projection(nodes)
        rule = structure.rule_table.rule(sub.first, sub.stop)
        f_sub = np.zeros((8, 3))
        solid_shell_force(P @ X_all, P @ u, *rule, f_sub)
        f_lam += P.T @ f_sub
    f_coh = np.zeros((n_nodes, 3))
    for interface in np.flatnonzero(state == InterfaceState.STRONG) + 1:
        nodes = enr.cohesive_nodes(
            columns, int(interface), n_plies, structure.extra.index, structure.n_base
        )
        P = projection(nodes)
        f_element = np.zeros((8, 3))
        damage = np.zeros(4)  # a fresh interface
        cohesive_element_force(P @ X_all, P @ u, config.cohesive.as_array(), damage, f_element)
        f_coh += P.T @ f_element
    return f_lam - f_coh, f_lam, f_coh


f_formula, f_lam, f_coh = formula_force(u_all())
scale = np.abs(f_package).max()
difference = np.abs(f_formula - f_package).max()
print(f"largest nodal force: {scale:.4e} N")
print(f"largest difference, package vs formula: {difference:.1e} N")
assert difference < 1e-12 * scale

# %% [markdown]
# ## What f_coh is
#
# In this package f_coh is the force that the interface tractions apply to the nodes: +N_a T dA
# on lower node a, -N_a T dA on upper node a. An opened interface pulls its two faces towards
# each other. For our uniform opening the normal traction is K_n * 2e-5 = 2 MPa over 0.5 mm^2,
# so the upper face (set B) is pulled down by about 1 N in total and the lower face (set A) up.
# (The frame follows the slightly rotated mid-surface, hence "about".)

# %%
set_a = enr.cohesive_nodes(columns, 4, n_plies, structure.extra.index, structure.n_base)[:4]
set_b = enr.cohesive_nodes(columns, 4, n_plies, structure.extra.index, structure.n_base)[4:]
area = 1.0 * 0.5
expected = config.cohesive.K_n * opening[2] * area
print(f"f_coh on set A: {f_coh[set_a].sum(axis=0)} N; on set B: {f_coh[set_b].sum(axis=0)} N")
assert abs(f_coh[set_b, 2].sum() + expected) < 1e-3 * expected
assert abs(f_coh[set_a, 2].sum() - expected) < 1e-3 * expected

# %% [markdown]
# ### The picture: f = f_lam - f_coh as arrows
#
# The front face (y = 0) of the cell seen from the side, with the x and z components of the
# nodal forces as arrows. Set-B nodes (red) are drawn a little to the right of their set-A twins
# (blue). f_lam comes from the subelements, f_coh from the cohesive element at interface 4: it
# pulls the two faces of the opened interface towards each other, so it acts on the set-A and
# set-B nodes only. Their difference f is what the solver uses. Each panel has its own arrow
# scale (the longest arrow is 0.25 mm long); the largest force of the panel is in its title.

# %%
node_colour = np.array(["k"] * n_nodes, dtype=object)
x_shift = np.zeros(n_nodes)
for key, local in structure.extra.index.items():
    _, interface, node_set = enr.key_parts(key, n_interfaces)
    node_colour[structure.n_base + local] = SET_COLOURS["AB"[node_set]]
    x_shift[structure.n_base + local] = 0.05 * node_set
front = np.flatnonzero(np.isclose(X_all[:, 1], 0.0))
fig, axes = plt.subplots(1, 3, figsize=(10, 3.8), sharey=True)
for ax, (name, force) in zip(
    axes, (("f_lam", f_lam), ("f_coh", f_coh), ("f", f_package)), strict=True
):
    draw_plies(ax, (0.0, 1.0), fractions, structure.laminate.thickness, labels=False)
    largest = np.abs(force[front][:, [0, 2]]).max()
    ax.quiver(
        X_all[front, 0] + x_shift[front],
        X_all[front, 2],
        force[front, 0],
        force[front, 2],
        color=list(node_colour[front]),
        angles="xy",
        scale_units="xy",
        scale=largest / 0.25,
        width=0.012,
    )
    ax.scatter(
        X_all[front, 0] + x_shift[front],
        X_all[front, 2],
        c=list(node_colour[front]),
        s=12,
        zorder=3,
    )
    ax.set(xlim=(-0.35, 1.35), xlabel="x (mm)", title=f"{name} (largest {largest:.2g} N)")
axes[0].set_ylabel("z (mm)")
# f_coh acts on the interface-4 nodes only, and f = f_lam - f_coh node by node
assert np.all(f_coh[: structure.n_base] == 0.0)
assert np.allclose(f_package, f_lam - f_coh, rtol=0.0, atol=1e-12 * scale)
finish(fig, "03_cell_force_arrows")

# %% [markdown]
# ## Why the minus sign: f is the gradient of the stored energy
#
# The stored energy is W = W_solid + W_coh. The internal force is f = dW/du. The subelement
# kernels return dW_solid/du = f_lam. The cohesive kernel returns the force on the nodes,
# f_coh = -dW_coh/du. Hence f = f_lam - f_coh. We check this with a central difference of W
# along a random direction d: (W(u + h d) - W(u - h d)) / (2 h) = f . d.

# %%
direction = rng.standard_normal((n_nodes, 3))
h = 1e-7
energy = []
u_saved = u_all()
for sign in (1.0, -1.0):
    shifted = u_saved + sign * h * direction
    u_base[:] = shifted[: structure.n_base]
    u_extra[:] = shifted[structure.n_base :]
    structure.internal_force()
    energy.append(sum(structure.internal_forces.energies()))
u_base[:], u_extra[:] = u_saved[: structure.n_base], u_saved[structure.n_base :]
slope = (energy[0] - energy[1]) / (2 * h)
predicted = float(np.sum(f_package * direction))
print(f"(W(u + h d) - W(u - h d)) / (2 h) = {slope:.9e} N, f . d = {predicted:.9e} N")
assert abs(slope - predicted) < 1e-6 * abs(predicted)

# %% [markdown]
# ## No net force
#
# The energy does not change when everything translates, so its gradient has no resultant:
# the nodal forces of f_lam, of f_coh and of f each sum to zero. And a rigid translation itself
# strains nothing and opens nothing: every nodal force is zero.

# %%
for name, f in (("f_lam", f_lam), ("f_coh", f_coh), ("f", f_package)):
    resultant = f.sum(axis=0)
    print(f"sum of {name:5s} over the nodes: {resultant} N")
    assert np.abs(resultant).max() < 1e-12 * scale

translation = np.array([0.3, -0.2, 0.1])  # mm
u_base[:] = translation
u_extra[:] = translation
structure.internal_force()
f_translated = np.vstack(
    [structure.f_base.array.reshape(-1, 3), structure.f_extra.array.reshape(-1, 3)]
)
largest = max(np.abs(f_translated).max(), np.abs(formula_force(u_all())[0]).max())
print(f"rigid translation: largest nodal force {largest:.1e} N")
assert largest < 1e-12 * scale

# %%
print("03_cell_force: all checks passed")
