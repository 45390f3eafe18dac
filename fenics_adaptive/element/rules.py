"""The packed integration rules of every (sub)element a laminate can hold: one rule per span of
plies [first, stop), the kernels' force rule and the lumped-mass rule, and the fastest wave
speed of each span (for the stable time step).

Units: mm, s, tonne, MPa.

Every consumer of packed rules (the structure's numba forces and masses, the ply-damage kernel,
the element forces of ``analysis.comparison``, the benchmark) takes them from one ``RuleTable``,
so that the rule of a span cannot differ between them.
"""

from __future__ import annotations

import numpy as np

from fenics_adaptive.element.subelement import (
    PackedMassRule,
    PackedRule,
    PackedRules,
    concatenate_rules,
    enhanced_parameter_maps,
    pack_mass_rule,
    pack_rule,
    solid_shell_lumped_masses,
    sublaminate_ply_zeta,
)
from fenics_adaptive.materials.laminate import (
    Laminate,
    bending_about_neutral_plane,
    ply_shear_factors,
)

# A one-ply (sub)element with one Gauss point through its thickness bends with zero energy (an
# hourglass mode through the thickness): it always gets at least this many.
ONE_PLY_POINTS = 2


def points_through_ply(n_plies: int, points_per_ply: int) -> int:
    """Gauss points through each ply of a (sub)element of ``n_plies`` plies: ``points_per_ply``,
    at least ``ONE_PLY_POINTS`` for one ply. The UFL forms of whole cells (``model.forms``) put
    ``points_per_ply`` in each ply and refuse a one-ply layer with one point: the same number
    for every layer they accept (``tests/test_rule_table.py`` holds the two paths equal)."""
    return points_per_ply if n_plies > 1 else max(points_per_ply, ONE_PLY_POINTS)


class RuleTable:
    """Packed rules of all spans [first, stop) of the plies of ``laminate``, in the order
    (0, 1), (0, 2), ..., (0, n), (1, 2), ... (``spans``); ``points_per_ply``: Gauss points
    through each ply of spans of more than one ply; ``shear_correction``: each span's transverse
    shear correction from the whole laminate's shear distribution, ply by ply
    (``materials.laminate.ply_shear_factors``: spans of several plies; 1 for one ply and
    without), and
    ``enhanced_strain``: the enhanced assumed thickness strain, ``preintegrate``: the spans'
    pre-integrated through-thickness rules where ``solid_shell.thickness_rule`` takes them
    (not for the ply-damage kernel, which needs its points ply by ply), all as the UFL forms of
    the same spans have them (``model.forms.LayeredModel``)."""

    def __init__(
        self,
        laminate: Laminate,
        points_per_ply: int,
        shear_correction: bool = True,
        enhanced_strain: bool = True,
        preintegrate: bool = False,
    ):
        n = laminate.n_plies
        fractions = laminate.ply_fractions
        stiffness = np.array(laminate.ply_stiffnesses())
        density = np.array([p.material.rho for p in laminate.plies])
        # mm/s; each ply's wave speed inverts its compliance: once, not per subelement
        ply_speeds = np.array([p.material.dilatational_wave_speed() for p in laminate.plies])
        self.n_plies = n
        self.points_per_ply = points_per_ply
        self.shear_correction = shear_correction
        self.enhanced_strain = enhanced_strain
        self.preintegrate = preintegrate
        self.spans: list[tuple[int, int]] = []
        self.rules: list[PackedRule] = []
        self.mass_rules: list[PackedMassRule] = []
        # rule index and fastest wave speed (mm/s) of each span, for whole arrays of spans
        self._rule_of_plies = np.full((n + 1, n + 1), -1, dtype=np.int64)
        self._speed_of_plies = np.zeros((n + 1, n + 1))
        # (m_xz, m_yz) of each ply of each span (``ply_shear_factors``)
        self._ply_shear: dict[tuple[int, int], np.ndarray] = {}
        for first in range(n):
            for stop in range(first + 1, n + 1):
                zeta = sublaminate_ply_zeta(fractions, first, stop)
                self._rule_of_plies[first, stop] = len(self.rules)
                self._speed_of_plies[first, stop] = ply_speeds[first:stop].max()
                self.spans.append((first, stop))
                points = points_through_ply(stop - first, points_per_ply)
                factors = ply_shear_factors(laminate, first, stop, shear_correction)
                self._ply_shear[first, stop] = factors
                self.rules.append(
                    pack_rule(
                        zeta, stiffness[first:stop], points, factors, enhanced_strain, preintegrate
                    )
                )
                self.mass_rules.append(pack_mass_rule(zeta, density[first:stop]))
        self.packed: PackedRules = concatenate_rules(self.rules)

    def __len__(self) -> int:
        return len(self.rules)

    def index(self, first: int, stop: int) -> int:
        """Index into ``packed`` (and ``rules``) of the rule of plies [first, stop)."""
        rule = int(self._rule_of_plies[first, stop]) if 0 <= first < stop <= self.n_plies else -1
        if rule < 0:
            raise ValueError(f"no ply span [{first}, {stop}) in a laminate of {self.n_plies} plies")
        return rule

    def rule_of(self, plies: np.ndarray) -> np.ndarray:
        """Rule index (int64) of each span of ``plies`` (n, 2) [first, stop)."""
        plies = np.asarray(plies, dtype=np.int64).reshape(-1, 2)
        return self._rule_of_plies[plies[:, 0], plies[:, 1]].astype(np.int64)

    def enhanced_parameter_maps(self, X: np.ndarray, plies: np.ndarray) -> np.ndarray:
        """(n, 4, 8, 3) small-strain maps from the nodal displacements of n (sub)elements with
        reference vertices ``X`` (n, 8, 3; mm) spanning ``plies`` (n, 2) [first, stop) to their
        enhanced thickness strain parameters (lines in ``solid_shell.ENHANCED_LINES`` order;
        zero where the rule has none), undamaged (``subelement.enhanced_parameter_maps``)."""
        maps = np.zeros((len(X), 4, 8, 3))
        enhanced_parameter_maps(X, self.rule_of(plies), *self.packed, maps)
        return maps

    def enhanced_parameters(self, X: np.ndarray, u: np.ndarray, plies: np.ndarray) -> np.ndarray:
        """(n, 4) the enhanced thickness strain parameters alpha (mm^3) of displacements ``u``
        (n, 8, 3; mm) (``enhanced_parameter_maps``)."""
        return np.einsum("ekai,eai->ek", self.enhanced_parameter_maps(X, plies), u)

    def ply_shear_factors(self, first: int, stop: int) -> np.ndarray:
        """(stop - first, 2) the factors (m_xz, m_yz) on the transverse shear stiffness of each
        ply in the rule of the span [first, stop) (``materials.laminate.ply_shear_factors``)."""
        self.index(first, stop)  # (refuses a span that is not one)
        return self._ply_shear[first, stop].copy()

    def wave_speed(self, plies: np.ndarray) -> np.ndarray:
        """Fastest dilatational wave speed (mm/s) of the plies of each span of ``plies``."""
        plies = np.asarray(plies, dtype=np.int64).reshape(-1, 2)
        return self._speed_of_plies[plies[:, 0], plies[:, 1]]

    def rule(self, first: int, stop: int) -> PackedRule:
        """The force rule of plies [first, stop) (``solid_shell_force(X, u, *rule, f)``)."""
        return self.rules[self.index(first, stop)]

    def mass_rule(self, first: int, stop: int) -> PackedMassRule:
        """The lumped-mass rule of plies [first, stop)."""
        return self.mass_rules[self.index(first, stop)]

    def lumped_masses(self, X: np.ndarray, first: np.ndarray, stop: np.ndarray) -> np.ndarray:
        """Lumped nodal masses (n, 8) tonne of (sub)elements with reference vertices X (n, 8, 3)
        mm spanning plies [first, stop) (n,) each."""
        masses = np.empty((len(X), 8))
        spans = first * (self.n_plies + 1) + stop
        for span in np.unique(spans):
            members = np.flatnonzero(spans == span)
            rule = self.mass_rule(*divmod(int(span), self.n_plies + 1))
            masses[members] = solid_shell_lumped_masses(X[members], *rule)
        return masses


def bending_stiffness_error(
    laminate: Laminate, points_per_ply: int, preintegrate: bool = False
) -> float:
    """Relative error of the bending stiffnesses D_11 and D_22 (the larger of the two) of an
    element of ``laminate`` as its rule integrates them through the thickness with
    ``points_per_ply`` Gauss points in each ply, against the exact integral (about the neutral
    plane, each ply's reduced plane-stress moduli). Negative: too flexible. One point per ply
    misses each ply's own h^3 / 12: about -1 / n^2 for n equal plies; two points are exact, and
    so is the pre-integrated rule wherever ``preintegrate`` gets it (its moments are exact:
    0)."""
    from fenics_adaptive.element.solid_shell import gauss_legendre_01, thickness_rule

    f = laminate.ply_fractions
    bounds = np.column_stack([f[:-1], f[1:]])
    stiffness = np.array(laminate.ply_stiffnesses())
    if thickness_rule(bounds, stiffness, points_per_ply, preintegrate).preintegrated:
        return 0.0
    z, moduli, (neutral, exact) = bending_about_neutral_plane(laminate)
    h = np.diff(z)
    s, w = gauss_legendre_01(points_per_ply)
    points = z[:-1, None] + h[:, None] * s[None, :]
    worst = 0.0
    for E, z_n, D in zip(moduli, neutral, exact, strict=True):
        ruled = np.sum(E[:, None] * h[:, None] * w[None, :] * (points - z_n) ** 2)
        error = ruled / D - 1.0
        worst = error if abs(error) > abs(worst) else worst
    return float(worst)


def integration_warnings(
    layer_laminates: list[Laminate], points_per_ply: int, preintegrate: bool = False
) -> list[str]:
    """One line for each mesh layer whose elements' bending stiffness the rule integrates off
    by more than 0.1 % (``bending_stiffness_error``): what a config with ``points_per_ply = 1``
    costs in accuracy where the pre-integrated rule is not taken (off, ply damage, or a layer
    where it is not positive definite). Refined subelements of one ply always get two
    points."""
    lines = []
    for k, laminate in enumerate(layer_laminates):
        error = bending_stiffness_error(laminate, points_per_ply, preintegrate)
        if abs(error) > 1e-3:
            where = (
                f"mesh layer {k + 1} ({laminate.n_plies} plies)"
                if len(layer_laminates) > 1
                else f"the laminate ({laminate.n_plies} plies)"
            )
            lines.append(
                f"warning: model.points_per_ply = {points_per_ply} integrates the bending "
                f"stiffness of {where} {100 * abs(error):.2g} % too "
                f"{'low' if error < 0 else 'high'} (one point per ply misses each ply's own "
                "h^3/12); points_per_ply = 2 integrates it exactly"
            )
    return lines
