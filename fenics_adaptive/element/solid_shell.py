"""The layered 8-node solid-shell element: its integration rule and its UFL forms.

One hexahedron spans the whole laminate (or, once refined, a sublaminate). Reference coordinates
(xi, eta, zeta) in [0, 1]^3, zeta through the thickness (the meshes guarantee it, see
``fenics_adaptive.meshes.beam``). Through the thickness (``thickness_rule``) the plies are
either integrated one by one, ``points_per_ply`` Gauss points inside each ply's own zeta range
with its own stiffness, or pre-integrated: three points whose stiffnesses carry the laminate's
moments of order 0, 1 and 2 (A, B, D), exact in bending for any number of plies at the cost of
three points (``preintegrated_stiffness``; the default of the models, where every point's
stiffness is positive definite). Nothing else about a ply is stored.

Transverse shear locking is removed with the selective in-plane rule that equals the
Bathe-Dvorkin assumed natural strain (ANS) interpolation on elements with parallelogram faces:

====================  ====================  =========================================
term of the energy    in-plane points       why
====================  ====================  =========================================
normal + xy           2 x 2                 exact for bilinear strains
gamma_xz^2            1 (xi) x 2 (eta)      ANS samples gamma_xz on xi = 1/2 lines
gamma_yz^2            2 (xi) x 1 (eta)      ANS samples gamma_yz on eta = 1/2 lines
gamma_xz * gamma_yz   1 x 1                 product of the two assumed fields
====================  ====================  =========================================

A ply rotated about the normal is monoclinic: its stiffness does not couple the transverse shears
(yz, xz) to the other four components, so these four terms are the whole strain energy. The rule
is expressed once (``ply_rules``) and used by both the UFL forms here and the numba subelement
kernel, which must agree with them to round-off.

Kinematics (``KINEMATICS``). "small": the linearised strain eps = sym(grad u). "finite": total
Lagrangian, the Green-Lagrange strain E = 1/2 (F^T F - I), F = I + Grad u, with the second
Piola-Kirchhoff stress S = C E (orthotropic St. Venant-Kirchhoff; C the ply stiffness rotated
about the normal in the REFERENCE frame, the same constant as for small strain), so a rigid
rotation gives E = 0 exactly. The selective rule applies term by term to the components of E
(2 E_xz on the 1 x 2 points, 2 E_yz on the 2 x 1 points, ...): the same point sets, hence no
shear locking in bending with large rotations either. The energy is 1/2 S : E, and the internal
force its derivative, f . v = integral of F S : Grad v over the reference volume.

Enhanced assumed thickness strain (Poisson thickness locking). With one element through the
thickness, the compatible thickness strain E_zz is constant in zeta, while bending makes the
in-plane strains linear in zeta: the Poisson coupling then leaves a spurious thickness stress
linear in zeta (about nu sigma_xx in the outer plies) and the element is too stiff. Following
the enhanced assumed strain (EAS) method of Simo and Rifai (1990) as solid-shell elements use it
for the thickness strain (Klinkel, Gruttmann and Wagner 1999, Comput. Struct. 71; Vu-Quoc and
Tan 2003, CMAME 192; Hauptmann and Schweizerhof 1998, IJNME 42), E_zz gets an enhanced part
linear in zeta:

    E_zz += alpha(xi, eta) g(zeta) / |det J|,    g = zeta - 1/2 (``enhanced_mode``),

alpha bilinear in (xi, eta), i.e. one parameter per line of the 2 x 2 in-plane points of the
"normal" term (four per element), the only points where E_zz enters the energy. Dividing by
|det J| (Simo-Rifai's j0/j) makes the enhanced strain orthogonal to every constant stress, so
the patch test holds on any hexahedron; the four modes g, g xi, g eta, g xi eta are not in the
compatible E_zz (constant in zeta where the top and bottom faces are parallel), so the element
gains no zero-energy mode. Each alpha is condensed on its own line: stationarity, sum over the
line's points of w g S_zz = 0, is linear in alpha for a St. Venant-Kirchhoff ply (small or
finite kinematics alike), hence alpha = -r / h with r = sum w g S_zz(compatible E) and
h = sum w g^2 C_zz,zz / |det J|. The element only loses stiffness (a condensed constraint), so
its highest frequency cannot rise and the stable time step estimates stay valid. Cost: the
numba kernels fold the condensation into their one pass over a line (a few multiply-adds per
point); the UFL forms assemble the residual r of every line once per force evaluation
(``model.forms``). With matrix cracks the thickness stress is piecewise linear in alpha, and the
damaged kernel takes Newton steps until the open points stop changing.

Curved cells (trapezoidal locking). Where a cell's vertical edges are not parallel, its thickness
strain is taken on those edges and interpolated between them (``element.assumed_strain``,
``thickness_strain_correction`` here, the marker ``bent`` of ``strain_energy_form``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import dolfinx
import numpy as np
import ufl
from dolfinx import fem

from fenics_adaptive.materials.laminate import Laminate
from fenics_adaptive.settings.kinds import Kinematics

KINEMATICS = tuple(Kinematics)  # the config's choices (settings.kinds)

GAUSS_2 = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])

# Energy terms of the selective rule, and the Voigt indices (xx, yy, zz, yz, xz, xy) they use.
NORMAL = (0, 1, 2, 5)
YZ, XZ = 3, 4
TERMS = ("normal", "shear_xz", "shear_yz", "shear_cross")
# in-plane points (xi, eta) and weights of each term
_IN_PLANE = {
    "normal": (np.array([[a, b] for a in GAUSS_2 for b in GAUSS_2]), np.full(4, 0.25)),
    "shear_xz": (np.array([[0.5, b] for b in GAUSS_2]), np.full(2, 0.5)),
    "shear_yz": (np.array([[a, 0.5] for a in GAUSS_2]), np.full(2, 0.5)),
    "shear_cross": (np.array([[0.5, 0.5]]), np.ones(1)),
}


def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n-point Gauss-Legendre rule on [0, 1] (points, weights: new arrays, the caller's to
    change)."""
    x, w = _gauss_legendre_01(n)
    return x.copy(), w.copy()


@functools.cache
def _gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    # (numpy's leggauss solves an eigenproblem: building the plate's rule table and refining it
    # asked for the rules some 1 100 times)
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def enhanced_mode(zeta: np.ndarray) -> np.ndarray:
    """g(zeta) = zeta - 1/2: the through-thickness shape of the enhanced thickness strain (module
    docstring); its integral over the element's reference thickness [0, 1] is zero."""
    return np.asarray(zeta, dtype=np.float64) - 0.5


# the enhanced thickness strain's in-plane parameters: one per line of the "normal" term's
# 2 x 2 points, its value there (Lagrange through GAUSS_2 in xi and in eta)
ENHANCED_LINES = np.array([[a, b] for a in GAUSS_2 for b in GAUSS_2])


def enhanced_in_plane_map(points: np.ndarray) -> np.ndarray:
    """(n, 4) map from the four line parameters alpha (``ENHANCED_LINES``) to the bilinear
    alpha(xi, eta) at in-plane reference ``points`` (n, >= 2; columns xi, eta)."""
    g1, g2 = GAUSS_2

    def lagrange(x, node):
        return (x - (g2 if node == g1 else g1)) / (node - (g2 if node == g1 else g1))

    points = np.asarray(points, dtype=np.float64)
    T = np.empty((len(points), len(ENHANCED_LINES)))
    for k, (a, b) in enumerate(ENHANCED_LINES):
        T[:, k] = lagrange(points[:, 0], a) * lagrange(points[:, 1], b)
    return T


def enhanced_nodal_map(points: np.ndarray) -> np.ndarray:
    """(n, 4) map T from the four line parameters alpha (``ENHANCED_LINES``) to the values of
    alpha(xi, eta) g(zeta) at reference ``points`` (n, 3): a trilinear field, so its values at
    the 8 vertices of a Q1 element give it exactly (``model.forms``)."""
    points = np.asarray(points, dtype=np.float64)
    return enhanced_in_plane_map(points) * enhanced_mode(points[:, 2])[:, None]


# the four vertical edges of a hexahedron: bottom vertex a (tensor order) and a's xi, eta
_COLUMN_XI_ETA = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])


def enhanced_displacement(X: np.ndarray, alpha: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """(m, 4, 3) displacement (mm) that the enhanced thickness strain of m (sub)elements adds at
    height ``zeta`` (m,) of their four vertical edges: the strain alpha g / |det J| integrated
    along each edge from its bottom, alpha(xi, eta) G(zeta) d / |det J| with d the edge
    (top - bottom vertex), G = (zeta^2 - zeta) / 2 the integral of g (zero at both faces, as
    g's mean is zero). Where a refinement splits an element at ``zeta``, adding it to the
    straight-line interpolation of the edge puts the new nodes on the element's own
    (compatible plus enhanced) thickness field, so that the subelements start with its
    thickness strain instead of its compatible part alone. Small strain: the edge is the
    reference one. ``X`` (m, 8, 3) reference vertices (mm), ``alpha`` (m, 4) line parameters
    in ``ENHANCED_LINES`` order (mm^3, ``subelement.enhanced_parameter_maps``)."""
    X = np.asarray(X, dtype=np.float64)
    zeta = np.asarray(zeta, dtype=np.float64)
    bottom, top = X[:, :4], X[:, 4:]
    edge = top - bottom  # d X / d zeta on each vertical edge
    # d X / d xi and d X / d eta on an edge: the face edges through it, blended in zeta
    blend = (1.0 - zeta)[:, None, None] * bottom + zeta[:, None, None] * top
    along_xi = blend[:, [1, 1, 3, 3]] - blend[:, [0, 0, 2, 2]]
    along_eta = blend[:, [2, 3, 2, 3]] - blend[:, [0, 1, 0, 1]]
    det = np.abs(np.einsum("mai,mai->ma", np.cross(along_xi, along_eta), edge))
    alpha_at_edges = alpha @ enhanced_in_plane_map(_COLUMN_XI_ETA).T  # (m, 4)
    G = 0.5 * (zeta**2 - zeta)
    return (alpha_at_edges * G[:, None] / det)[:, :, None] * edge


class ThicknessRule(NamedTuple):
    """The points through the thickness of one (sub)element and the stiffness each carries:
    point p sits at ``zeta[p]`` with weight ``weights[p]`` and stiffness
    ``stiffness[stiffness_of_point[p]]``. Per ply (``preintegrated`` False), the stiffnesses
    are the plies' and ``stiffness_of_point`` is the ply; pre-integrated, they are the three
    stiffnesses of ``preintegrated_stiffness`` and the points carry no ply."""

    zeta: np.ndarray  # (m,) on [0, 1]
    weights: np.ndarray  # (m,), summing to 1
    stiffness: np.ndarray  # (s, 6, 6) MPa, shell frame
    stiffness_of_point: np.ndarray  # (m,) int64
    preintegrated: bool


def preintegrated_stiffness(
    ply_bounds: np.ndarray, ply_stiffness: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The laminate pre-integrated through the thickness onto three points: (zeta (3,), weights
    (3,), S (3, 6, 6)) such that sum_p w_p S_p zeta_p^j = sum_k C_k integral over ply k of
    zeta^j for j = 0, 1, 2 (the laminate's A, B and D moments, reference thickness [0, 1]).

    Why it is exact: on a cell whose top and bottom faces are parallel (J independent of
    zeta, the meshes' flat cells and their subelements), the small strain, with the enhanced
    thickness strain, is affine in zeta on every vertical line, so each term of the energy and
    of the force is a moment of order 0, 1 or 2 of the stiffness through the thickness; the
    three points reproduce those moments for any number of plies (Abaqus' "general shell
    section", integrated before the analysis, does the same for the stress resultants). The
    points are the 3-point Gauss rule, so a one-material (sub)element gets S_p = C at each:
    exact to degree 5. On cells whose faces are not parallel the rule stays a quadrature of the
    same order. ``ply_bounds`` (n, 2) on [0, 1], ``ply_stiffness`` (n, 6, 6)."""
    zeta, weights = gauss_legendre_01(3)
    lo, hi = ply_bounds[:, 0], ply_bounds[:, 1]
    moments = np.array(
        [
            np.einsum("k,kab->ab", (hi ** (j + 1) - lo ** (j + 1)) / (j + 1), ply_stiffness)
            for j in range(3)
        ]
    )
    vandermonde = np.array([weights * zeta**j for j in range(3)])  # [j, p]
    S = np.einsum("pj,jab->pab", np.linalg.inv(vandermonde), moments)
    return zeta, weights, 0.5 * (S + S.transpose(0, 2, 1))


def _positive_definite(S: np.ndarray) -> bool:
    """Each point's stiffness positive definite on the four normal components and on the two
    transverse shears (the blocks the selective rule uses)."""
    for block in (NORMAL, (YZ, XZ)):
        sub = S[:, block][:, :, block]
        scale = np.abs(sub).max()
        if np.linalg.eigvalsh(sub).min() <= 1e-10 * scale:
            return False
    return True


def thickness_rule(
    ply_bounds: np.ndarray, ply_stiffness: np.ndarray, points_per_ply: int, preintegrate: bool
) -> ThicknessRule:
    """The through-thickness rule of a (sub)element of plies ``ply_bounds`` (n, 2) on its own
    reference thickness [0, 1] with stiffnesses ``ply_stiffness`` (n, 6, 6).

    ``preintegrate``: the three pre-integrated points (``preintegrated_stiffness``), exact in
    bending for any number of plies, where they are fewer than two points per ply (two plies
    or more) and each point's stiffness is positive definite (so that the element energy is
    positive for any displacement, parallel faces or not; a stiff-skin sandwich core, or some
    two-ply spans, make the middle point indefinite). Otherwise, and always without
    ``preintegrate``, ``points_per_ply`` Gauss points in each ply (two integrate the bending
    stiffness exactly; ``rules.bending_stiffness_error`` says what one costs)."""
    bounds = np.asarray(ply_bounds, dtype=np.float64)
    C = np.asarray(ply_stiffness, dtype=np.float64)
    n = len(bounds)
    if preintegrate and n >= 2:
        zeta, weights, S = preintegrated_stiffness(bounds, C)
        if _positive_definite(S):
            return ThicknessRule(zeta, weights, S, np.arange(3, dtype=np.int64), True)
    z, w = gauss_legendre_01(points_per_ply)
    thickness = bounds[:, 1] - bounds[:, 0]
    return ThicknessRule(
        zeta=(bounds[:, :1] + thickness[:, None] * z[None, :]).ravel(),
        weights=(thickness[:, None] * w[None, :]).ravel(),
        stiffness=C,
        stiffness_of_point=np.repeat(np.arange(n, dtype=np.int64), len(z)),
        preintegrated=False,
    )


def term_rules(zeta: np.ndarray, weights: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Reference points (m n_term, 3) and weights of each energy term for the through-thickness
    points ``zeta`` (m,) of weights ``weights``: each point's in-plane points of the term,
    point by point."""
    rules = {}
    for term, (xy, w_xy) in _IN_PLANE.items():
        points = np.array([[p[0], p[1], zk] for zk in zeta for p in xy])
        weights_term = np.array([wk * w for wk in weights for w in w_xy])
        rules[term] = (points, weights_term)
    return rules


def ply_rules(
    zeta_lo: float, zeta_hi: float, points_per_ply: int
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Reference points (n, 3) and weights (n,) of each energy term for one ply occupying
    [zeta_lo, zeta_hi] of the element's reference thickness. Summed over the plies of an element
    the weights of every term add up to 1 (the reference volume)."""
    z, wz = gauss_legendre_01(points_per_ply)
    return term_rules(zeta_lo + (zeta_hi - zeta_lo) * z, (zeta_hi - zeta_lo) * wz)


def mass_rule(zeta_lo: float, zeta_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """2x2x2 Gauss rule inside one ply: integrates rho * N_i * det(J) of a hexahedron exactly
    (the row sums of the consistent mass)."""
    z, wz = gauss_legendre_01(2)
    z = zeta_lo + (zeta_hi - zeta_lo) * z
    wz = (zeta_hi - zeta_lo) * wz
    points = np.array([[a, b, c] for c in z for a in GAUSS_2 for b in GAUSS_2])
    weights = np.array([0.25 * w for w in wz for _ in range(4)])
    return points, weights


@dataclass(frozen=True)
class PlyGroup:
    """Plies of one element that share a stiffness (same material and angle): their points are
    integrated by one custom-quadrature measure per term with one constant stiffness."""

    stiffness: np.ndarray  # 6x6, shell frame
    rho: float
    ply_indices: tuple[int, ...]
    rules: dict[str, tuple[np.ndarray, np.ndarray]]
    mass_points: np.ndarray
    mass_weights: np.ndarray


def per_ply_shear_factors(shear_factors, n_plies: int) -> np.ndarray:
    """(n_plies, 2) transverse shear factors (m_xz, m_yz) per ply from ``shear_factors``: None
    (1), one pair (k_xz, k_yz) for every ply alike, or (n_plies, 2)."""
    if shear_factors is None:
        return np.ones((n_plies, 2))
    m = np.asarray(shear_factors, dtype=np.float64)
    if m.shape == (2,):
        return np.tile(m, (n_plies, 1))
    if m.shape != (n_plies, 2):
        raise ValueError(f"shear_factors: expected (2,) or ({n_plies}, 2), got {m.shape}")
    return m


def shear_weights(ply_factors: np.ndarray) -> np.ndarray:
    """(n_plies, 4) the factors on the weights of each ply's points in each energy term
    (``TERMS`` order) for its transverse shear factors ``ply_factors`` (n_plies, 2: m_xz,
    m_yz; ``materials.laminate.ply_shear_factors``): 1, m_xz, m_yz, sqrt(m_xz m_yz). Scaling
    a point's weights scales its energy exactly as scaling C_55, C_44 (and C_45) there by
    them would, in the elastic and the damaged kernels alike, and leaves the point-averaged
    strains as they are."""
    m = np.asarray(ply_factors, dtype=np.float64).reshape(-1, 2)
    return np.column_stack([np.ones(len(m)), m[:, 0], m[:, 1], np.sqrt(m[:, 0] * m[:, 1])])


def span_shear_weights(
    ply_factors: np.ndarray, ply_bounds: np.ndarray, ply_stiffness: np.ndarray
) -> np.ndarray:
    """(4,) ``shear_weights`` of a whole span whose points belong to no ply (the
    pre-integrated rule): of its plies' factors ``ply_factors`` (n, 2) the means weighted by
    the plies' thickness (``ply_bounds`` (n, 2)) times shear modulus (``ply_stiffness``
    (n, 6, 6)): the factor that gives the span the same shear stiffness (the element's
    correction k, ``materials.laminate.element_shear_factors``)."""
    m = np.asarray(ply_factors, dtype=np.float64).reshape(-1, 2)
    bounds = np.asarray(ply_bounds, dtype=np.float64)
    C = np.asarray(ply_stiffness, dtype=np.float64)
    t = bounds[:, 1] - bounds[:, 0]
    G = np.column_stack([C[:, XZ, XZ], C[:, YZ, YZ]]) * t[:, None]
    k = (G * m).sum(axis=0) / G.sum(axis=0)
    return shear_weights(k[None, :])[0]


def ply_groups(
    laminate: Laminate, points_per_ply: int, shear_factors: np.ndarray | None = None
) -> list[PlyGroup]:
    """The plies of an element of ``laminate`` grouped by stiffness, each with its rules;
    ``shear_factors``: each ply's (m_xz, m_yz) on its transverse shear terms
    (``per_ply_shear_factors``, ``shear_weights``)."""
    factors = shear_weights(per_ply_shear_factors(shear_factors, laminate.n_plies))
    fractions = laminate.ply_fractions
    keys: dict[tuple, list[int]] = {}
    for k, ply in enumerate(laminate.plies):
        keys.setdefault((ply.material, ply.angle % 360.0), []).append(k)
    groups = []
    for indices in keys.values():
        rules = {term: ([], []) for term in TERMS}
        mass_points, mass_weights = [], []
        for k in indices:
            for term, (p, w) in ply_rules(fractions[k], fractions[k + 1], points_per_ply).items():
                rules[term][0].append(p)
                rules[term][1].append(factors[k, TERMS.index(term)] * w)
            p, w = mass_rule(fractions[k], fractions[k + 1])
            mass_points.append(p)
            mass_weights.append(w)
        ply = laminate.plies[indices[0]]
        groups.append(
            PlyGroup(
                stiffness=ply.stiffness(),
                rho=ply.material.rho,
                ply_indices=tuple(indices),
                rules={t: (np.vstack(p), np.concatenate(w)) for t, (p, w) in rules.items()},
                mass_points=np.vstack(mass_points),
                mass_weights=np.concatenate(mass_weights),
            )
        )
    return groups


@dataclass(frozen=True)
class StiffnessGroup:
    """Points of an element's strain energy that share one stiffness: one custom-quadrature
    measure per term, one constant stiffness (a ply group, or one pre-integrated point)."""

    stiffness: np.ndarray  # 6x6, shell frame, MPa
    rules: dict[str, tuple[np.ndarray, np.ndarray]]


def energy_groups(
    laminate: Laminate,
    points_per_ply: int,
    shear_factors: np.ndarray | None = None,
    preintegrate: bool = False,
) -> list[StiffnessGroup]:
    """The strain energy's stiffness groups of an element of ``laminate`` under the
    through-thickness rule ``thickness_rule`` chooses (``preintegrate``, ``points_per_ply``):
    one group per pre-integrated point, or the plies grouped by stiffness (``ply_groups``);
    ``shear_factors``: each ply's (m_xz, m_yz) on the transverse shear terms
    (``per_ply_shear_factors``; pre-integrated: their span mean, ``span_shear_weights``)."""
    shear_factors = per_ply_shear_factors(shear_factors, laminate.n_plies)
    C = np.array(laminate.ply_stiffnesses())
    f = laminate.ply_fractions
    rule = thickness_rule(np.column_stack([f[:-1], f[1:]]), C, points_per_ply, preintegrate)
    if not rule.preintegrated:
        return [
            StiffnessGroup(g.stiffness, g.rules)
            for g in ply_groups(laminate, points_per_ply, shear_factors)
        ]
    factor = span_shear_weights(shear_factors, np.column_stack([f[:-1], f[1:]]), C)
    groups = []
    for p in range(len(rule.zeta)):
        rules = term_rules(rule.zeta[p : p + 1], rule.weights[p : p + 1])
        groups.append(
            StiffnessGroup(
                stiffness=rule.stiffness[rule.stiffness_of_point[p]],
                rules={t: (points, factor[TERMS.index(t)] * w) for t, (points, w) in rules.items()},
            )
        )
    return groups


def check_monoclinic(C: np.ndarray) -> None:
    """The selective rule drops normal/shear coupling; it must be zero for the rule to be exact."""
    coupling = np.abs(C[np.ix_(NORMAL, (YZ, XZ))]).max()
    if coupling > 1e-12 * np.abs(C).max():
        raise ValueError("ply stiffness couples transverse shear to in-plane strains")


def displacement_gradient(
    u: ufl.core.expr.Expr, frame: ufl.core.expr.Expr | None = None
) -> ufl.core.expr.Expr:
    """H = Grad u, in the global frame, or in the cell's ``frame`` (rows e1, e2, e3: the
    components R H R^T, a curved shell's cell frame, ``element.geometry.cell_frames``)."""
    H = ufl.grad(u)
    return H if frame is None else frame * H * frame.T


def voigt_small_strain(
    u: ufl.core.expr.Expr, frame: ufl.core.expr.Expr | None = None
) -> ufl.core.expr.Expr:
    """Small (linearised) strain in Voigt order (xx, yy, zz, yz, xz, xy), engineering shears,
    in the global frame or the cell's ``frame`` (``displacement_gradient``)."""
    e = ufl.sym(displacement_gradient(u, frame))
    return ufl.as_vector([e[0, 0], e[1, 1], e[2, 2], 2 * e[1, 2], 2 * e[0, 2], 2 * e[0, 1]])


def voigt_green_lagrange(
    u: ufl.core.expr.Expr, frame: ufl.core.expr.Expr | None = None
) -> ufl.core.expr.Expr:
    """Green-Lagrange strain E = 1/2 (H + H^T + H^T H), H = Grad u, in Voigt order with
    engineering shears (2 E_ij), in the global frame or the cell's ``frame`` (E transforms
    as H does, R E R^T). Written from H rather than as 1/2 (F^T F - I): the latter loses
    the small strains of a stiff laminate to cancellation against I."""
    H = displacement_gradient(u, frame)
    E = 0.5 * (H + H.T + H.T * H)
    return ufl.as_vector([E[0, 0], E[1, 1], E[2, 2], 2 * E[1, 2], 2 * E[0, 2], 2 * E[0, 1]])


def voigt_strain(
    u: ufl.core.expr.Expr, kinematics: str = "small", frame: ufl.core.expr.Expr | None = None
) -> ufl.core.expr.Expr:
    """The strain measure of ``kinematics`` ("small" or "finite"), Voigt order, in the global
    frame or the cell's ``frame``."""
    if kinematics == Kinematics.SMALL:
        return voigt_small_strain(u, frame)
    if kinematics == Kinematics.FINITE:
        return voigt_green_lagrange(u, frame)
    raise ValueError(f"kinematics must be one of {', '.join(KINEMATICS)} (got {kinematics!r})")


def _edge_distances(points: np.ndarray) -> tuple[float, float]:
    """(xi (1 - xi), eta (1 - eta)) shared by every point (n, >= 2) of a term's rule (the
    selective rule's points sit on the 2 x 2 Gauss lines and the mid-lines, where they are
    1/6 and 1/4): the weights of ``assumed_strain``'s correction on that term's points."""
    c = points[:, :2] * (1.0 - points[:, :2])
    if np.ptp(c, axis=0).max() > 1e-12:
        raise ValueError("the term's points do not share xi (1 - xi) and eta (1 - eta)")
    return float(c[0, 0]), float(c[0, 1])


def thickness_strain_correction(
    u: ufl.core.expr.Expr,
    c_xi: float,
    c_eta: float,
    kinematics: str = "small",
    frame: ufl.core.expr.Expr | None = None,
) -> ufl.core.expr.Expr:
    """The Voigt strain (engineering shears) that sampling the thickness strain on the cell's
    vertical edges adds at points with xi (1 - xi) = ``c_xi``, eta (1 - eta) = ``c_eta``:
    dE k (x) k (``element.assumed_strain``; there the numba kernels' copy), in the global
    frame or the cell's ``frame``. The reference derivatives of the directors and of u,zeta are
    taken as physical gradients times the Jacobian's columns."""
    mesh = ufl.domain.extract_unique_domain(u)
    J = ufl.Jacobian(mesh)

    def along(f, r):  # d f / d X_r of a vector field f
        return ufl.grad(f) * J[:, r]

    A = J[:, 2]  # the reference director X,zeta
    b = ufl.grad(u) * J[:, 2]  # u,zeta
    b_xi, b_eta = along(b, 0), along(b, 1)
    dE = c_xi * ufl.dot(along(A, 0), b_xi) + c_eta * ufl.dot(along(A, 1), b_eta)
    if kinematics == Kinematics.FINITE:
        dE += 0.5 * (c_xi * ufl.dot(b_xi, b_xi) + c_eta * ufl.dot(b_eta, b_eta))
    k = ufl.JacobianInverse(mesh)[2, :]  # grad zeta
    if frame is not None:
        k = frame * k
    return dE * ufl.as_vector(
        [k[0] ** 2, k[1] ** 2, k[2] ** 2, 2 * k[1] * k[2], 2 * k[0] * k[2], 2 * k[0] * k[1]]
    )


class SeparateKernels:
    """Hands every custom-quadrature integral its own subdomain id, hence its own FFCx kernel.

    Why: FFCx 0.11 hoists values that are constant within a quadrature loop (Jacobian and
    gradient pieces) to the top of the kernel under names shared by all the loops of that
    kernel, so two custom rules compiled into one kernel read each other's values and the
    result is silently wrong (tests/test_solid_shell.py reproduces it). Each id may cover any
    set of cells; ids may overlap.
    """

    def __init__(self, mesh: dolfinx.mesh.Mesh):
        self.mesh = mesh
        self.subdomains: list[tuple[int, np.ndarray]] = []

    def measure(self, points: np.ndarray, weights: np.ndarray, cells: np.ndarray) -> ufl.Measure:
        subdomain_id = len(self.subdomains) + 1
        self.subdomains.append((subdomain_id, np.asarray(cells, dtype=np.int32)))
        return ufl.Measure(
            "dx",
            domain=self.mesh,
            subdomain_data=self.subdomains,  # the same list object for every integral
            subdomain_id=subdomain_id,
            metadata={
                "quadrature_rule": "custom",
                "quadrature_points": points,
                "quadrature_weights": weights,
            },
        )


def owned_cells(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    return np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)


def strain_energy_form(
    u: fem.Function,
    groups: list[StiffnessGroup] | list[PlyGroup],
    kernels: SeparateKernels | None = None,
    cells: np.ndarray | None = None,
    selective: bool = True,
    kinematics: str = "small",
    enhanced: ufl.Coefficient | None = None,
    frame: ufl.Coefficient | None = None,
    bent: ufl.Coefficient | None = None,
) -> ufl.Form:
    """Strain energy (N mm) of the layered solid-shell with the selective (ANS) rule over
    ``cells`` (default: all owned cells), as a UFL form in the displacement ``u``. The internal
    force is its derivative. ``selective=False`` integrates the transverse shear with the full
    2x2 rule instead: the plain hexahedron, which locks in bending (kept to show what the
    selective rule buys). ``kinematics``: "small" (1/2 sigma : eps) or "finite" (1/2 S : E with
    the Green-Lagrange strain E; see the module docstring). ``enhanced``: a scalar Q1 field
    alpha(xi, eta) g(zeta) per cell (``enhanced_nodal_map``), whose value / |det J| is added
    to the thickness strain (the enhanced assumed strain; its parameters are condensed by the
    caller); None: the compatible strain alone. ``frame``: a curved shell's cell frames (a DG0
    3 x 3 function, rows e1, e2, e3), in which the strain is taken; None: the global frame.
    ``bent``: a DG0 marker, 1 on the cells whose directors bend, where the thickness strain is
    sampled on the vertical edges (``element.assumed_strain``), 0 elsewhere; None: nowhere."""
    mesh = u.function_space.mesh
    kernels = kernels if kernels is not None else SeparateKernels(mesh)
    cells = cells if cells is not None else owned_cells(mesh)
    energy = 0
    compatible = voigt_strain(u, kinematics, frame)

    def strain(rule):  # the strain on the points of a term's rule
        if bent is None:
            return compatible
        c_xi, c_eta = _edge_distances(rule[0])
        return compatible + bent * thickness_strain_correction(u, c_xi, c_eta, kinematics, frame)

    for group in groups:
        C = group.stiffness
        check_monoclinic(C)
        C_normal = ufl.as_matrix(C[np.ix_(NORMAL, NORMAL)].tolist())
        rules = {term: group.rules[term if selective else "normal"] for term in TERMS}
        eps = strain(rules["normal"])
        e_zz = eps[2]
        if enhanced is not None:
            e_zz = e_zz + enhanced / abs(ufl.JacobianDeterminant(mesh))
        e_normal = ufl.as_vector([eps[0], eps[1], e_zz, eps[5]])  # NORMAL's components
        energy += (
            0.5 * ufl.dot(e_normal, C_normal * e_normal) * kernels.measure(*rules["normal"], cells)
        )
        eps = strain(rules["shear_xz"])
        energy += 0.5 * C[XZ, XZ] * eps[XZ] ** 2 * kernels.measure(*rules["shear_xz"], cells)
        eps = strain(rules["shear_yz"])
        energy += 0.5 * C[YZ, YZ] * eps[YZ] ** 2 * kernels.measure(*rules["shear_yz"], cells)
        if C[XZ, YZ] != 0.0:
            eps = strain(rules["shear_cross"])
            energy += C[XZ, YZ] * eps[XZ] * eps[YZ] * kernels.measure(*rules["shear_cross"], cells)
    return energy


def internal_force_form(
    u: fem.Function,
    v: ufl.Argument,
    groups: list[StiffnessGroup] | list[PlyGroup],
    kernels: SeparateKernels | None = None,
    cells: np.ndarray | None = None,
    selective: bool = True,
    kinematics: str = "small",
    bent: ufl.Coefficient | None = None,
) -> ufl.Form:
    """Internal force f_int(u) . v (N mm for a virtual displacement v); nonlinear in u for
    ``kinematics="finite"``; ``bent`` as ``strain_energy_form`` takes it."""
    energy = strain_energy_form(u, groups, kernels, cells, selective, kinematics, bent=bent)
    return ufl.derivative(energy, u, v)


def lumped_mass_form(
    v: ufl.Argument,
    groups: list[PlyGroup],
    kernels: SeparateKernels | None = None,
    cells: np.ndarray | None = None,
) -> ufl.Form:
    """Row-sum lumped mass as a linear form: m_i = sum_plies rho * integral(N_i) (tonne), the
    same value in each of the three components of node i."""
    mesh = v.ufl_function_space().mesh
    kernels = kernels if kernels is not None else SeparateKernels(mesh)
    cells = cells if cells is not None else owned_cells(mesh)
    ones = ufl.as_vector([1.0, 1.0, 1.0])
    mass = 0
    for group in groups:
        dx = kernels.measure(group.mass_points, group.mass_weights, cells)
        mass += group.rho * ufl.dot(ones, v) * dx
    return mass
