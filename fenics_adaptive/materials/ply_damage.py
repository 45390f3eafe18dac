"""Intralaminar ply damage: 3-D Hashin failure indices and a crack-band matrix damage law.

Units: N, mm, s, tonne. Strengths and stiffnesses in MPa, fracture energies in N/mm (= mJ/mm^2),
energy densities in MPa (= mJ/mm^3), lengths in mm.

Frames. Everything here is in the ply's material frame: 1 along the fibres, 2 in-plane
transverse, 3 the laminate normal; Voigt order (11, 22, 33, 23, 13, 12) with engineering shear
strains, as in ``laminate``. ``strain_rotation`` maps shell-frame strains to it.

Failure indices (Hashin 1980, 3-D) of a material-frame stress s, S12 the in-plane and S23 the
transverse shear strength (the kernels pass the nominal stress C(d) eps, which is the effective
stress C0 eps of the undamaged ply until the matrix damages):

    fibre tension     (s11 >= 0):       F = (s11/XT)^2 + (s12^2 + s13^2)/S12^2
    fibre compression (s11 < 0):        F = (s11/XC)^2
    matrix tension    (s22 + s33 >= 0): F = ((s22+s33)/YT)^2 + (s23^2 - s22 s33)/S23^2
                                            + (s12^2 + s13^2)/S12^2
    matrix compression (s22 + s33 < 0): F = [(YC/(2 S23))^2 - 1] (s22+s33)/YC
                                            + ((s22+s33)/(2 S23))^2 + (s23^2 - s22 s33)/S23^2
                                            + (s12^2 + s13^2)/S12^2

The indices returned are *exposure factors*, not F: index = 1/lambda, lambda the factor by
which the current stress must be scaled to reach F = 1. They are linear in the load
(index(k s) = k index(s) for k > 0), reach 1.0 exactly when F does, and so compare directly
with a load fraction such as 0.8. For the three quadratic forms the index is sqrt(F); matrix
compression, F = a + b with a linear and b quadratic in s, gives (a + sqrt(a^2 + 4 b)) / 2. The
index of the mode that does not apply (fibre compression under s11 >= 0, ...) is 0. As in
Hashin's paper the fibre tension index contains the longitudinal shears: pure in-plane shear at
S12 gives a fibre tension index of 1 as well.

Matrix damage (one scalar d per ply per element, never decreasing). A matrix crack has its
normal along axis 2: it takes the transverse normal stress s22 (while open) and the shears s12
and s23 on its faces. With c = C0[:, 1] (the 22 column of the undamaged stiffness) the free
energy and the stress are

    psi(eps, d) = 1/2 eps.C0.eps - d y(eps)
    y(eps)      = <s22>^2 / (2 C0_22) + s12^2 / (2 G12) + s23^2 / (2 G23)   (s = C0 eps)
    sigma       = C(d) eps,   C(d) = C0 - d (open c c^T / C0_22 + G12 e12 e12^T + G23 e23 e23^T)

(<x> = max(x, 0); "open" means s22 > 0, a closed crack keeps the full transverse normal
stiffness, so transverse compression is never degraded). C(d) is symmetric, positive definite
for d < 1 (it is (1 - d) C0 plus a positive semi-definite part), and at d = 1 it is the
stiffness with sigma_22 = sigma_12 = sigma_23 = 0 (the fibre and 13-shear stiffness only).
Equivalently, in compliance form, S22 -> S22 + d / ((1 - d) C0_22), S44 -> S44 / (1 - d),
S66 -> S66 / (1 - d), all couplings unchanged: E2, G23, G12 and the Poisson couplings through
E2 are degraded consistently; in uniaxial transverse stress the ply responds with the modulus
1 / (S22 + d / ((1 - d) C0_22)). The energy release rate -dpsi/dd = y depends on the strain
only, which is what makes the dissipation exact (below).

Initiation: when the matrix index (tension or compression, whichever applies) of s = C0 eps first
reaches 1 with y > 0, the onset energy y0 = y / index^2 (the value of y where the index is 1 on
the proportional path through the current state) is stored; it does not change afterwards (an
implicit driver must therefore detect the onset on its elastic predictor, as an explicit step
does). In an element y is the mean over the ply's points (below), so a ply whose mean s22 is
compressive while some of its points pull (a neutral axis inside the ply) has y > 0 from
those points, and its compression index can start the crack. Pure transverse compression
(y = 0) never initiates damage: matrix compression, like
fibre failure, is then an index only; but the compression branch does initiate cracking when
the crack-face tractions are nonzero: in-plane shear under transverse compression, or s22 > 0
with s22 + s33 < 0 (a ply of a cross-ply pulled across its fibres can be there), which the
tension branch alone would never damage. Modes changing after the onset keep y0 (and take G_c
of the current mixity).

Evolution (bilinear softening, crack band). With l_c the width of the crack band (the
element's extent across the crack, given by the caller),

    G_c   = G2c + (G6c - G2c) B,  B = y_shear / y        (Benzeggagh-Kenane, exponent 1)
    rho   = sqrt(y / y0),         rho_F = G_c / (l_c y0)
    d     = (1 - 1/rho) / (1 - 1/rho_F)  for 1 <= rho < rho_F,  1 for rho >= rho_F,
    d     = max(d_old, d).

This is the law d = delta_F (delta - delta_0) / (delta (delta_F - delta_0)) of the cohesive
element in the equivalent displacement delta = l_c eps_eq, eps_eq = sqrt(2 y / K) (K = C0_22
in transverse tension: eps_eq is then the transverse strain under uniaxial strain; K = G12 in
in-plane shear: eps_eq = gamma_12), onset delta_0 = l_c sqrt(2 y0 / K), final
delta_F = 2 G_c / sigma_eq0, sigma_eq0 = sqrt(2 K y0). The dissipated energy is int y dd; as
d is a function of y alone (for a fixed mode mixity), it equals G_c / l_c per unit volume,
i.e. G_c per unit crack area, for ANY strain path that keeps the mode fixed (pure transverse
tension: G2c; pure in-plane shear: G6c), whatever l_c and whatever the other strains do (the
lateral constraint of the neighbouring plies included). In uniaxial transverse stress the
stress-strain curve is exactly bilinear: peak YT at YT/E2, zero at 2 G2c / (YT l_c).

Softening needs rho_F > 1, and in uniaxial transverse stress a monotone strain needs
rho_F > C0_22 / E2, i.e. l_c < 2 E2 G2c / YT^2; in shear l_c < 2 G12 G6c / S12^2
(``max_band_width``; ``check_band_width`` raises ``InputError`` beyond). A path whose onset
energy is higher than the pure modes' (e.g. transverse tension under through-thickness
compression) can still reach rho_F <= 1: the ply then fails at once (d = 1), dissipating
l_c y0 > G_c per area, as the cohesive law does.

Fibre damage (with the fibre fracture energies Gft, Gfc given; one scalar d_f per ply per
element, never decreasing). A ply whose fibres break, in tension or in a kink band, carries
nothing any more: the whole ply stiffness degrades,

    psi(eps, d, d_f) = (1 - d_f) psi_m(eps, d),   psi_m = 1/2 eps.C0.eps - d y(eps)
    sigma            = (1 - d_f) C(d) eps,

as LS-DYNA's MAT54/58 and Matzenmiller-Lubliner-Taylor's models treat a ply after fibre
failure (its stresses go to zero). Chosen over a crack with normal along axis 1 that would take
s11, s12 and s13 only (the matrix crack's form for the fibre direction): two such rank-one
degradations of the same C0 are not positive definite together (C0 - c1 c1^T / C0_11 - c2 c2^T
/ C0_22 has a negative 2x2 minor), while a scale factor is for every (d, d_f), keeps the
matrix law as it is, and makes a ply whose fibres have all broken what erosion removes. The
fibres' energy release rate is y_f = -dpsi/dd_f = psi_m(eps, d), the ply's strain energy
density: again a function of the strain alone at fixed d. The element kernels take it as the
mean over the ply's integration points (what scaling every point of the ply releases: a ply
bent within its thickness holds more than the energy of its mean strain), with the matrix
damage of before the update (less what the update's own matrix increment released).
Initiation on the maximum fibre stress of Hashin and Rotem (1973), s11 = XT or s11 = -XC with
s the nominal stress C(d) eps (Abaqus' alpha = 0: the longitudinal shears crack the matrix,
they do not break fibres; the recorded fibre tension index keeps Hashin's 1980 shear term),
onset energy y0_f = y_f / index^2 of its own for each mode (tension while s11 >= 0,
compression while s11 < 0: a ply that began to kink still breaks in tension at XT), then the
law of the matrix crack on sqrt(y_f / y0_f) with the mode's onset and G = Gft or Gfc, d_f the
largest either mode has reached, and l_c the cell's extent along the fibres (the width of the
band a crack across the fibres runs through). The dissipated energy is G / l_c per unit volume
for any path at a fixed mode and matrix damage: G per unit area of the crack across the
fibres. In uniaxial fibre stress the curve is exactly bilinear, peak XT at XT / E1, and
softening needs l_c < 2 E1 Gft / XT^2 (and 2 E1 Gfc / XC^2 in compression). Matrix damage
growing in a ply whose fibres have partly failed dissipates (1 - d_f) of what it would in an
intact one, and fibres breaking in the update that cracks the matrix further release psi_m at
the new matrix damage: what the two increments book together is the energy the ply loses at
that strain.

State of one ply of one element (``N_STATE`` floats, zero initially): S_D matrix damage, S_Y0
its onset energy (0 until initiation), S_FT, S_FC, S_MT, S_MC the largest fibre tension / fibre
compression / matrix tension / matrix compression index seen so far, evaluated with the
nominal stress C(d) eps (the effective one while d = 0), S_DISSIPATED the energy density (MPa =
mJ/mm^3) the ply's damage (matrix and fibre) has dissipated so far, S_Y_LAST the energy
release rate y of the last update; S_DF the fibre damage, S_Y0FT and S_Y0FC its onset energies
in tension and compression, S_YF_LAST its y_f of the last update, S_FIBRE_DISSIPATED the fibres'
share of S_DISSIPATED, S_ERODED the strain energy density the ply's element held when erosion
removed it (``subelement``).

Dissipation from the law's own increments. The stiffness loses (1 - RESIDUAL) dd (A_open + A_1)
per update, and y = 1/2 eps.(A_open + A_1).eps (the released part of the strain energy density),
so under the solver's trapezoidal work the energy density not stored over an update is exactly
(1 - RESIDUAL) dd 1/2 eps_n.A.eps_{n+1}: ``ply_damage_update`` accumulates (1 - RESIDUAL) dd
sqrt(y_n y_{n+1}), equal to it on a proportional path (consistent, second order otherwise).
An element softens every point of a ply with the one d, so it releases the mean over the
ply's points of 1/2 eps_p.A.eps_p dd: the law takes y as that mean (its normal part with each
point's crack open where that point's s22 > 0, as the force opens it), not as y of the ply's
mean strain, which is smaller where the strain varies through the ply (Jensen: a ply bent
about its own mid-plane, the strain rising linearly from zero across it, releases 4/3 of it).
With y of the mean strain the law booked 3/4 of what such a ply released, and its crack band
dissipated 4/3 of its fracture energy; the onset stays that of the failure index of the
ply's mean stress. The transverse shear part (sigma_23^2 / (2 G23)) is still that of the
ply's mean strain: the rule samples its two shears at their own points. A seeded flaw
(``ply_damage_state``: y0 preset for a share of YT) now starts where the points' mean of
<s22>^2 reaches it, in a bent ply a little below that share of YT in mean stress. The
element's transverse shear energy carries each ply's shear factor
m (``solid_shell.shear_weights``: m times that of the sampled strain; ``materials.laminate
.ply_shear_factors``: the plies' shares of the laminate's shear flow), so the law takes the
ply's stress of its strain with the shear strains times sqrt(m): its failure indices see the
ply's share of the shear flow (an outer ply of a bent ESL cell little, as in the
laminate), and its energy release rate what the element releases (with G23 gamma_23 it would
book 1 / m times that).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from numba import njit

from fenics_adaptive.errors import InputError
from fenics_adaptive.materials.laminate import VOIGT_PAIRS, Ply, PlyMaterial, rotation_about_z
from fenics_adaptive.settings.materials import (
    F_G2C,
    F_G6C,
    F_GFC,
    F_GFT,
    F_S12,
    F_S23,
    F_XC,
    F_XT,
    F_YC,
    F_YT,
    N_FAILURE,
    PlyFailure,
)

# Slots of a ply's parameter row (ply_params): the failure slots (PlyFailure.as_array), then
# the undamaged stiffness C0_21, C0_22, C0_23 (the normal entries of its 22 column), G12, G23.
P_C21, P_C22, P_C23, P_G12, P_G23 = range(N_FAILURE, N_FAILURE + 5)
N_PLY_PARAMS = N_FAILURE + 5
# Slots of a ply's damage state.
S_D, S_Y0, S_FT, S_FC, S_MT, S_MC, S_DISSIPATED, S_Y_LAST = range(8)
S_DF, S_Y0FT, S_Y0FC, S_YF_LAST, S_FIBRE_DISSIPATED, S_ERODED = range(8, 14)
N_STATE = 14
# Columns of a band-width row: the cell's extent across the fibres (matrix crack), along them
# (fibre crack).
BAND_MATRIX, BAND_FIBRE = 0, 1
# A fully cracked ply keeps this fraction of the stiffness its matrix damage removes: the
# stiffness uses (1 - RESIDUAL) d. Without it a cell whose plies have all cracked is a
# zero-stiffness mechanism, and crack closure on such a cell has blown explicit runs up. The law
# softens towards G_c / (1 - RESIDUAL), so that the dissipated energy stays G_c per crack area.
RESIDUAL = 0.01


# ---------------------------------------------------------------------------------------------
# crack band width


def band_limits(material: PlyMaterial, failure: PlyFailure) -> tuple[tuple[str, float, str], ...]:
    """The snap-back limits of the crack band width (mm), as (energy field, limit, formula):
    matrix cracks in pure transverse tension (2 E2 G2c / YT^2) and pure in-plane shear (2 G12
    G6c / S12^2) for the band across the fibres; with fibre damage, fibre tension (2 E1 Gft /
    XT^2) and compression (2 E1 Gfc / XC^2) for the band along them. A band must stay strictly
    below its limits."""
    limits = [
        ("G2c", 2.0 * material.E2 * failure.G2c / failure.YT**2, "2 E2 G2c / YT^2"),
        ("G6c", 2.0 * material.G12 * failure.G6c / failure.S12**2, "2 G12 G6c / S12^2"),
    ]
    if failure.fibre_damage:
        limits += [
            ("Gft", 2.0 * material.E1 * failure.Gft / failure.XT**2, "2 E1 Gft / XT^2"),
            ("Gfc", 2.0 * material.E1 * failure.Gfc / failure.XC**2, "2 E1 Gfc / XC^2"),
        ]
    return tuple(limits)


def max_band_width(material: PlyMaterial, failure: PlyFailure) -> float:
    """Largest crack band width l_c (mm) across the fibres for which the matrix softens without
    snap-back in pure transverse tension and pure in-plane shear (``band_limits``)."""
    return min(limit for _, limit, _ in band_limits(material, failure)[:2])


def check_band_width(
    material: PlyMaterial,
    failure: PlyFailure,
    band_width: float,
    fibre_band_width: float | None = None,
) -> None:
    """Raise ``InputError`` if ``band_width`` (mm, across the fibres) is not below the matrix
    limits of ``band_limits``, or ``fibre_band_width`` (mm, along them; None: not checked) not
    below the fibre ones."""
    key = f"materials.{material.name}.failure"
    limits = band_limits(material, failure)
    widths = [band_width] * 2 + [fibre_band_width] * (len(limits) - 2)
    for (field, limit, formula), width in zip(limits, widths, strict=True):
        if width is not None and not width < limit:
            across = "across the fibres" if field in ("G2c", "G6c") else "along the fibres"
            crack = "matrix" if field in ("G2c", "G6c") else "fibre"
            raise InputError(
                f"{key}.{field}",
                f"a cell is {width:.6g} mm {across}, at least the snap-back limit {formula} = "
                f"{limit:.6g} mm of the {crack} crack band: use smaller cells or a larger "
                f"{field}",
            )


def crack_band_width(X: np.ndarray, angle_deg: float) -> float:
    """Width (mm) of a hexahedral cell across a matrix crack of a ply at ``angle_deg``: the
    extent of its mid-surface (the mean of the bottom and top vertices, DOLFINx order, zeta
    through the thickness) along the in-plane transverse axis 2. For an a x b rectangle and a
    ply at angle t this is a |sin t| + b |cos t|, the area of the cells a straight crack along
    the fibres crosses per unit crack length in a structured mesh. The band of a crack across
    the fibres (fibre failure) is the extent along axis 1: ``crack_band_width(X, angle - 90)``."""
    X = np.asarray(X, dtype=np.float64).reshape(8, 3)
    mid = 0.5 * (X[:4] + X[4:])
    axis_2 = rotation_about_z(angle_deg)[:, 1]
    projection = mid @ axis_2
    return float(projection.max() - projection.min())


def crack_band_widths(X: np.ndarray, angle_deg: float) -> np.ndarray:
    """(2,) mm: the band widths of a ply at ``angle_deg`` in the cell X, across its fibres
    (matrix cracks, column BAND_MATRIX) and along them (fibre cracks, BAND_FIBRE)."""
    return np.array([crack_band_width(X, angle_deg), crack_band_width(X, angle_deg - 90.0)])


# ---------------------------------------------------------------------------------------------
# packing for the kernels


def strain_rotation(angle_deg: float) -> np.ndarray:
    """6x6 T with eps_material = T eps_shell (Voigt, engineering shears) for a ply at
    ``angle_deg``; the shell-frame stiffness of a material-frame C is T^T C T."""
    R = rotation_about_z(angle_deg)
    T = np.empty((6, 6))
    for b, (k, l) in enumerate(VOIGT_PAIRS):
        E = np.zeros((3, 3))
        E[k, l] = E[l, k] = 1.0 if k == l else 0.5
        E_material = R.T @ E @ R
        T[:, b] = [E_material[i, j] * (1.0 if i == j else 2.0) for i, j in VOIGT_PAIRS]
    return T


def _drop_round_off(C: np.ndarray) -> np.ndarray:
    C = 0.5 * (C + C.T)
    C[np.abs(C) < 1e-14 * np.abs(C).max()] = 0.0
    return C


def degradation_matrices(material: PlyMaterial) -> np.ndarray:
    """(2, 6, 6) material-frame matrices A with C(d) = C0 - d (open A[0] + A[1]): A[0] =
    c c^T / C0_22 (transverse normal, only while the crack is open), A[1] = G12 e12 e12^T +
    G23 e23 e23^T (the two shears on the crack faces)."""
    C0 = material.stiffness()
    c = C0[:, 1].copy()
    A = np.zeros((2, 6, 6))
    A[0] = np.outer(c, c) / C0[1, 1]
    A[1, 3, 3] = C0[3, 3]
    A[1, 5, 5] = C0[5, 5]
    return A


def damaged_material_stiffness(
    material: PlyMaterial, d: float, crack_open: bool, fibre_damage: float = 0.0
) -> np.ndarray:
    """6x6 material-frame secant stiffness (1 - d_f) C(d) of a ply with matrix damage d and
    fibre damage ``fibre_damage`` (both with the RESIDUAL kept)."""
    A = degradation_matrices(material)
    kept = 1.0 - RESIDUAL
    matrix = material.stiffness() - kept * d * ((A[0] if crack_open else 0.0) + A[1])
    return (1.0 - kept * fibre_damage) * matrix


def ply_params_row(material: PlyMaterial, failure: PlyFailure) -> np.ndarray:
    """A ply's parameter row (N_PLY_PARAMS,): failure slots, then C0_21, C0_22, C0_23, G12,
    G23."""
    C0 = material.stiffness()
    row = np.empty(N_PLY_PARAMS)
    row[:N_FAILURE] = failure.as_array()
    row[P_C21], row[P_C22], row[P_C23] = C0[0, 1], C0[1, 1], C0[2, 1]
    row[P_G12], row[P_G23] = C0[5, 5], C0[3, 3]
    return row


class PackedPlyDamage(NamedTuple):
    """Damage data of the plies of a packed rule, row k for the rule's ply k (parallel to
    ``PackedRule.stiffness`` / ``PackedRules.stiffness``). The fields are kernel arguments in
    order: ``solid_shell_force_damaged(X, u, *rule, *ply_damage, band_width, state, f_out)``."""

    strain_to_stress: np.ndarray  # (n, 6, 6): shell-frame strain -> material-frame C0 eps
    degradation: np.ndarray  # (n, 2, 6, 6): shell-frame T^T A T of degradation_matrices
    params: np.ndarray  # (n, N_PLY_PARAMS): ply_params_row


def pack_ply_damage(plies: Sequence[Ply], failures: Mapping[str, PlyFailure]) -> PackedPlyDamage:
    """Damage data of ``plies`` (those of a (sub)element, bottom to top, in the order its rule
    has them), with ``failures`` by material name."""
    n = len(plies)
    M = np.empty((n, 6, 6))
    A = np.empty((n, 2, 6, 6))
    params = np.empty((n, N_PLY_PARAMS))
    for k, ply in enumerate(plies):
        failure = failures.get(ply.material.name)
        if failure is None:
            raise InputError(
                f"materials.{ply.material.name}.failure", "missing (ply damage needs it)"
            )
        T = strain_rotation(ply.angle)
        M[k] = ply.material.stiffness() @ T
        for i, A_material in enumerate(degradation_matrices(ply.material)):
            A[k, i] = _drop_round_off(T.T @ A_material @ T)
        params[k] = ply_params_row(ply.material, failure)
    return PackedPlyDamage(M, A, params)


def concatenate_ply_damage(packed: Sequence[PackedPlyDamage]) -> PackedPlyDamage:
    """Concatenate in the order of ``subelement.concatenate_rules`` of the matching rules."""
    return PackedPlyDamage(
        *(np.ascontiguousarray(np.concatenate(parts)) for parts in zip(*packed, strict=True))
    )


def degraded_shell_stiffness(
    stiffness: np.ndarray,
    ply_damage: PackedPlyDamage,
    k: int,
    d: float,
    crack_open: bool,
    fibre_damage: float = 0.0,
) -> np.ndarray:
    """Shell-frame secant stiffness of ply k with matrix damage d and fibre damage
    ``fibre_damage``: what the kernels use (stiffness[k] is the ply's undamaged shell-frame
    stiffness, e.g. ``PackedRule.stiffness``)."""
    A = ply_damage.degradation[k]
    kept = 1.0 - RESIDUAL
    matrix = stiffness[k] - kept * d * ((A[0] if crack_open else 0.0) + A[1])
    return (1.0 - kept * fibre_damage) * matrix


def nominal_ply_stresses(
    strains: np.ndarray,
    plies: Sequence[Ply],
    damage: np.ndarray | None = None,
    fibre_damage: np.ndarray | None = None,
) -> np.ndarray:
    """Material-frame stress (1 - d_f) C(d) T eps (MPa) of plies with shell-frame strains
    ``strains`` (n, n_plies, 6), matrix damage ``damage`` and fibre damage ``fibre_damage``
    (n, n_plies; None: undamaged): what the kernels compute at those strains. The crack is open
    where the undamaged s22 is tensile."""
    out = np.empty_like(strains)
    for k, ply in enumerate(plies):
        eps = strains[:, k] @ strain_rotation(ply.angle).T
        effective = eps @ ply.material.stiffness().T
        out[:, k] = effective
        if damage is not None:
            A = degradation_matrices(ply.material)
            d = (1.0 - RESIDUAL) * damage[:, k, None]
            open_crack = (effective[:, 1] > 0.0)[:, None]
            out[:, k] -= d * (open_crack * (eps @ A[0].T) + eps @ A[1].T)
        if fibre_damage is not None:
            out[:, k] *= 1.0 - (1.0 - RESIDUAL) * fibre_damage[:, k, None]
    return out


# ---------------------------------------------------------------------------------------------
# numba kernels
#
# Inlined into their callers (numba IR): the damaged solid-shell kernel calls the update for
# every ply of every element, and the calls cost 10 % of it. Inlined code takes the caller's
# compiler flags: there, the kernels' fast-math subset, which changes results at round-off only.


@njit(cache=True, inline="always", error_model="numpy")
def hashin_indices(s11, s22, s33, s23, s13, s12, params):
    """Exposure-factor indices (fibre tension, fibre compression, matrix tension, matrix
    compression) of the material-frame stress; ``params`` starts with the failure slots."""
    S12 = params[F_S12]
    S23 = params[F_S23]
    shear = (s12 * s12 + s13 * s13) / (S12 * S12)
    if s11 >= 0.0:
        r = s11 / params[F_XT]
        ft = math.sqrt(r * r + shear)
        fc = 0.0
    else:
        ft = 0.0
        fc = -s11 / params[F_XC]
    sn = s22 + s33
    transverse = (s23 * s23 - s22 * s33) / (S23 * S23)
    if sn >= 0.0:
        r = sn / params[F_YT]
        mt = math.sqrt(max(r * r + transverse + shear, 0.0))
        mc = 0.0
    else:
        YC = params[F_YC]
        q = YC / (2.0 * S23)
        a = (q * q - 1.0) * sn / YC
        r = sn / (2.0 * S23)
        b = max(r * r + transverse + shear, 0.0)
        mt = 0.0
        mc = 0.5 * (a + math.sqrt(a * a + 4.0 * b))
    return ft, fc, mt, mc


@njit(cache=True, inline="always", error_model="numpy")
def _record_indices(s11, s22, s33, s23, s13, s12, params, state):
    ft, fc, mt, mc = hashin_indices(s11, s22, s33, s23, s13, s12, params)
    state[S_FT] = max(state[S_FT], ft)
    state[S_FC] = max(state[S_FC], fc)
    state[S_MT] = max(state[S_MT], mt)
    state[S_MC] = max(state[S_MC], mc)
    return max(mt, mc)


@njit(cache=True, inline="always", error_model="numpy")
def _softened(y, y0, G, band_width):
    """The damage of the bilinear crack-band law at energy release rate y > y0 (onset y0,
    fracture energy G (N/mm) over the band ``band_width`` (mm), the RESIDUAL stiffness
    included)."""
    rho_f = G / ((1.0 - RESIDUAL) * band_width * y0)
    rho = math.sqrt(y / y0)
    if rho >= rho_f:  # also covers rho_f <= 1 (no softening possible: instant failure)
        return 1.0
    return (1.0 - 1.0 / rho) / (1.0 - 1.0 / rho_f)


@njit(cache=True, inline="always", error_model="numpy")
def matrix_release_rates(s22, s12, params):
    """The matrix's energy release rates (MPa) at a point of effective material-frame stresses
    s22, s12: <s22>^2 / (2 C22) (the crack opens where s22 > 0) and s12^2 / (2 G12)."""
    return max(s22, 0.0) ** 2 / (2.0 * params[P_C22]), s12 * s12 / (2.0 * params[P_G12])


@njit(cache=True, inline="always", error_model="numpy")
def ply_damage_update(sigma, energy_density, params, band_width, state, point_rates):
    """Update one ply's damage state (N_STATE,) in place from its effective material-frame
    stress ``sigma`` (6,) = C0 eps (in an element of several plies, eps with the transverse
    shears its energy carries: ``subelement``), its matrix's energy release rates
    ``point_rates`` (2,): ``matrix_release_rates`` of its points, their mean over an element's
    (MPa; ``subelement._ply_release_rates``), and strain energy density
    ``energy_density`` = psi_m
    (MPa; read only with fibre damage: 1/2 eps.C(d).eps at the matrix damage d of before the
    update, at a point, the mean of it over the ply's points in the element kernels);
    ``params`` is its ply_params_row,
    ``band_width`` (2,) its l_c across and along the fibres (mm, BAND_MATRIX, BAND_FIBRE).
    Returns True if the crack is open (s22 > 0): the kernels then degrade with both
    degradation matrices, else with the shear one only. The recorded indices are those of the
    nominal stress C(d) eps (equal to the effective one while d = 0): once the matrix has
    cracked, the opening strain no longer loads the fibres through the Poisson coupling."""
    kept = 1.0 - RESIDUAL
    s22 = sigma[1]
    crack_open = s22 > 0.0
    y_normal = point_rates[0]  # what the points release (module docstring)
    y_shear = point_rates[1] + sigma[3] * sigma[3] / (2.0 * params[P_G23])
    y = y_normal + y_shear
    y_last = state[S_Y_LAST]
    state[S_Y_LAST] = y
    y0 = state[S_Y0]
    recorded = False
    if y0 == 0.0:  # not initiated, so d = 0: the effective stress is the nominal one
        matrix = _record_indices(
            sigma[0], sigma[1], sigma[2], sigma[3], sigma[4], sigma[5], params, state
        )
        recorded = True
        if matrix >= 1.0 and y > 0.0:
            y0 = y / (matrix * matrix)
            state[S_Y0] = y0
    d_old = state[S_D]
    if y0 > 0.0 and y > y0:
        G2c = params[F_G2C]
        d = _softened(y, y0, G2c + (params[F_G6C] - G2c) * (y_shear / y), band_width[0])
        if d > d_old:
            state[S_D] = d
            # the consistent increment (module docstring), of the fibres' intact share
            released = kept * (d - d_old) * math.sqrt(y * y_last)
            state[S_DISSIPATED] += (1.0 - kept * state[S_DF]) * released
    d = state[S_D]
    s11 = sigma[0]
    if d > 0.0:
        opening = kept * d * s22 / params[P_C22] if crack_open else 0.0
        s11 = sigma[0] - opening * params[P_C21]
        _record_indices(
            s11,
            sigma[1] - opening * params[P_C22],
            sigma[2] - opening * params[P_C23],
            (1.0 - kept * d) * sigma[3],
            sigma[4],
            (1.0 - kept * d) * sigma[5],
            params,
            state,
        )
    elif not recorded:
        _record_indices(sigma[0], sigma[1], sigma[2], sigma[3], sigma[4], sigma[5], params, state)
    if params[F_GFT] > 0.0:  # psi_m at the matrix damage of after this update
        released = kept * (d - d_old) * y
        _fibre_update(s11, energy_density - released, params, band_width[1], state)
    return crack_open


@njit(cache=True, inline="always", error_model="numpy")
def _fibre_update(s11, y_fibre, params, band_width, state):
    """Fibre damage of one ply from its nominal fibre stress ``s11`` (MPa) and energy release
    rate ``y_fibre`` = psi_m (MPa) over the band ``band_width`` along the fibres (mm)."""
    y_last = state[S_YF_LAST]
    state[S_YF_LAST] = y_fibre
    tension = s11 >= 0.0
    onset = S_Y0FT if tension else S_Y0FC
    y0 = state[onset]
    if y0 == 0.0:  # this mode has not initiated
        index = s11 / params[F_XT] if tension else -s11 / params[F_XC]
        if index < 1.0 or y_fibre <= 0.0:
            return
        y0 = y_fibre / (index * index)
        state[onset] = y0
    if y_fibre <= y0:
        return
    d = _softened(y_fibre, y0, params[F_GFT] if tension else params[F_GFC], band_width)
    d_old = state[S_DF]
    if d > d_old:
        state[S_DF] = d
        released = (1.0 - RESIDUAL) * (d - d_old) * math.sqrt(y_fibre * y_last)
        state[S_DISSIPATED] += released
        state[S_FIBRE_DISSIPATED] += released


# ---------------------------------------------------------------------------------------------
# plain-Python wrappers


class FailureIndices(NamedTuple):
    fibre_tension: float
    fibre_compression: float
    matrix_tension: float
    matrix_compression: float


def failure_indices(failure: PlyFailure, stress: np.ndarray) -> FailureIndices:
    """Hashin exposure-factor indices of a material-frame stress (6,) (MPa)."""
    s = np.asarray(stress, dtype=np.float64)
    return FailureIndices(*hashin_indices(s[0], s[1], s[2], s[3], s[4], s[5], failure.as_array()))


def new_state(*shape: int) -> np.ndarray:
    """Zero damage state of shape (*shape, N_STATE), e.g. new_state(n_cells, n_plies)."""
    return np.zeros((*shape, N_STATE))


def material_point_update(
    material: PlyMaterial,
    failure: PlyFailure,
    strain: np.ndarray,
    band_width: float | Sequence[float],
    state: np.ndarray,
) -> tuple[np.ndarray, float]:
    """One ply at one point: material-frame strain (6,) -> material-frame stress (6,) (MPa) and
    secant strain energy density 1/2 sigma.eps (MPa), updating ``state`` (N_STATE,) in place.
    ``band_width``: l_c across and along the fibres (mm), or one value for both. The same law
    as the element kernels (for tests, plots and calibration)."""
    eps = np.asarray(strain, dtype=np.float64)
    effective = material.stiffness() @ eps
    bands = np.broadcast_to(np.asarray(band_width, dtype=np.float64), (2,)).copy()
    matrix = damaged_material_stiffness(material, state[S_D], bool(effective[1] > 0.0))
    psi_m = 0.5 * float(eps @ matrix @ eps)  # the fibres' energy release rate
    params = ply_params_row(material, failure)
    rates = np.array(matrix_release_rates(effective[1], effective[5], params))
    crack_open = ply_damage_update(effective, psi_m, params, bands, state, rates)
    sigma = damaged_material_stiffness(material, state[S_D], bool(crack_open)) @ eps
    sigma *= 1.0 - (1.0 - RESIDUAL) * state[S_DF]
    return sigma, 0.5 * float(sigma @ eps)
