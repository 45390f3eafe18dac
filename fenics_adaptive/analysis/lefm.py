"""Beam-theory LEFM references of the delamination tests: the cantilever beams (DCB, TCB), the
end-notched flexure (ENF) and mixed-mode bending (MMB, the superposition of the two); the force
on each test's propagation branch, and a run's history compared with it.

Units: N, mm, s, tonne (force N, opening mm, fracture energy N/mm, modulus MPa).

Each arm is a cantilever of bending stiffness E I = E1 b h^3 / 12 (width b, thickness h; E1
the arm's narrow-beam bending modulus, ``arm_moduli``: the fibre modulus of a unidirectional
arm, 12 / (h^3 d11) of a multidirectional one) pulled
open by delta at its end. Eliminating the crack length between the arm's compliance and the
energy release rate at G = GIc gives the propagation branch P = K^1.5 / sqrt(3 E I delta),
K = sqrt(2 b E I GIc). The same branch follows from root-rotation-corrected beam theory
(Hashemi 1990), which writes the compliance and G with one effective length a + chi h;
``root_rotation_correction`` gives chi for the record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fenics_adaptive.materials.cohesive import critical_energy
from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.settings.config import RunConfig
from fenics_adaptive.settings.materials import CohesiveLaw

SMALLEST_OPENING = 1e-12  # mm: the branch is infinite at delta = 0


def arm_thickness(laminate: Laminate, interface: int) -> float:
    """Thickness (mm) of the arm above ply interface ``interface`` (between ply ``interface``
    and ply ``interface + 1``, counted from 1 at the bottom): the plies above it."""
    return sum(p.thickness for p in laminate.plies[interface:])


@dataclass(frozen=True)
class ArmModuli:
    """The moduli (MPa) beam theory takes for the two equal arms of a specimen split at an
    interface: ``E1`` their narrow-beam bending modulus 12 / (h^3 d11) (d = inverse of the
    arm's ABD: the fibre modulus of a unidirectional arm), ``E2`` and ``G12`` those of the
    laminate's first ply, for the root rotation (``root_rotation_correction``) and the shear
    compliance."""

    E1: float
    E2: float
    G12: float


def arm_moduli(laminate: Laminate, interface: int, width: float) -> ArmModuli:
    """``ArmModuli`` of ``laminate`` split at ply interface ``interface`` (1-based), ``width``
    mm wide. Raises ValueError when the arms bend differently (moduli apart by more than
    1e-6): the equal-arm theories do not apply."""
    arms = (Laminate(laminate.plies[:interface]), Laminate(laminate.plies[interface:]))
    moduli = [12.0 * a.narrow_beam_bending_stiffness(width) / (width * a.thickness**3)
              for a in arms]  # fmt: skip
    if abs(moduli[0] - moduli[1]) > 1e-6 * max(moduli):
        raise ValueError(
            f"the arms below and above interface {interface} bend with moduli {moduli[0]:.6g} "
            f"and {moduli[1]:.6g} MPa: the beam theory of equal arms does not apply"
        )
    first = laminate.plies[0].material
    return ArmModuli(float(moduli[1]), first.E2, first.G12)


def propagation_force(
    delta: np.ndarray, modulus: float, width: float, arm: float, GIc: float
) -> np.ndarray:
    """Force (N) on the LEFM propagation branch, P = K^1.5 / sqrt(3 E I delta),
    K = sqrt(2 b E I GIc), E I = E1 b h^3 / 12.

    Parameters:
        delta: arm openings (mm), any shape.
        modulus: the arm's bending modulus E1 (MPa).
        width: the beam's width b (mm).
        arm: the arm's thickness h (mm).
        GIc: the mode-I fracture energy (N/mm).

    Returns:
        The force at each opening (N), the shape of ``delta``.
    """
    EI = modulus * width * arm**3 / 12.0
    K = np.sqrt(2.0 * width * EI * GIc)
    return K**1.5 / np.sqrt(3.0 * EI * np.maximum(delta, SMALLEST_OPENING))


def tcb_lefm_force(config: RunConfig, delta: np.ndarray, interface: int = 6) -> np.ndarray:
    """Force (N) on the propagation branch of the arm above ply interface ``interface`` of a
    beam config (the TCB demo's top arm: interface 6), opened by ``delta`` (mm); the arm's
    modulus is E1 of the beam's first ply. See ``propagation_force``."""
    plies = config.laminate.plies
    return propagation_force(
        delta,
        plies[0].material.E1,
        config.mesh.width,
        arm_thickness(config.laminate, interface),
        config.cohesive.GIc,
    )


def root_rotation_correction(material: PlyMaterial | ArmModuli) -> float:
    """chi of corrected beam theory (Hashemi 1990), dimensionless: the arm's effective length is
    a + chi h, chi = sqrt(E1 / (11 G12) (3 - 2 (Gamma / (1 + Gamma))^2)),
    Gamma = 1.18 sqrt(E1 E2) / G12."""
    gamma = 1.18 * np.sqrt(material.E1 * material.E2) / material.G12
    return float(
        np.sqrt(material.E1 / (11.0 * material.G12) * (3.0 - 2.0 * (gamma / (1.0 + gamma)) ** 2))
    )


def lefm_comparison(config: RunConfig, history: dict, interface: int = 6) -> dict:
    """A run's force on the propagation branch against LEFM (``tcb_lefm_force``), where the
    crack is longer than 5 arm thicknesses (shorter cracks are not yet on the branch).

    Parameters:
        config: the run's config (two delaminations of equal length: the crack length is the
            delaminated area over twice the width).
        history: the run's history columns (``io.output.read_history``): ``displacement`` (mm),
            ``reaction_force`` (N), ``delaminated_area`` (mm^2).
        interface: the ply interface below the arm.

    Returns:
        ``points`` on the branch, ``crack_length_range_mm``, ``force_over_lefm_mean``, ``_min``
        and ``_max`` (None without points on the branch), and ``root_rotation_chi`` of the first
        ply's material.
    """
    arm = arm_thickness(config.laminate, interface)
    delta = np.array(history["displacement"])
    force = np.array(history["reaction_force"])
    length = np.array(history["delaminated_area"]) / (2 * config.mesh.width)
    on_branch = length > 5 * arm
    ratio = force[on_branch] / tcb_lefm_force(config, delta[on_branch], interface)
    return {
        "points": int(on_branch.sum()),
        "crack_length_range_mm": [float(length[on_branch].min()), float(length.max())]
        if on_branch.any()
        else [],
        "force_over_lefm_mean": float(ratio.mean()) if on_branch.any() else None,
        "force_over_lefm_min": float(ratio.min()) if on_branch.any() else None,
        "force_over_lefm_max": float(ratio.max()) if on_branch.any() else None,
        "root_rotation_chi": root_rotation_correction(config.laminate.plies[0].material),
    }


def dcb_force(
    opening: np.ndarray, modulus: float, width: float, arm: float, GIc: float, crack: float
) -> np.ndarray:
    """Force (N) of a symmetric double cantilever beam (two equal arms) against the total
    opening Delta (mm) of its load line, by corrected beam theory: the linear branch
    P = 3 E I Delta / (2 a^3) of the crack length ``crack`` a (mm, from the load line; pass
    a0 + chi h for the root-rotation correction) until G = P^2 a^2 / (b E I) reaches GIc, then
    the propagation branch P = (b E I GIc)^(3/4) sqrt(2 / (3 E I Delta)), which the correction
    leaves unchanged. E I = E1 b h^3 / 12 of one arm (``arm``: its thickness h, mm).

    Parameters:
        opening: the load line's openings Delta (mm), any shape.
        modulus: the arms' bending modulus E1 (MPa).
        width: the beam's width b (mm).
        arm: one arm's thickness h (mm).
        GIc: the mode-I fracture energy (N/mm).
        crack: the initial (effective) crack length (mm).

    Returns:
        The force at each opening (N), the shape of ``opening``.
    """
    EI = modulus * width * arm**3 / 12.0
    opening = np.maximum(np.asarray(opening, dtype=float), SMALLEST_OPENING)
    linear = 3.0 * EI * opening / (2.0 * crack**3)
    branch = (width * EI * GIc) ** 0.75 * np.sqrt(2.0 / (3.0 * EI * opening))
    return np.minimum(linear, branch)


def dcb_initiation_force(modulus: float, width: float, arm: float, GIc: float, crack: float):
    """The force (N) at which a symmetric DCB with crack length ``crack`` (mm, effective)
    reaches GIc: sqrt(b E I GIc) / a (``dcb_force``'s two branches meet there)."""
    EI = modulus * width * arm**3 / 12.0
    return float(np.sqrt(width * EI * GIc) / crack)


# the share of the load point's whole travel over which ``averaged_peak`` averages
PEAK_TRAVEL_SHARE = 0.01


def averaged_peak(displacement, force, share: float = PEAK_TRAVEL_SHARE) -> float:
    """The largest force (N) of a quasi-static test once its ringing is averaged out: the
    largest mean of the rows' forces over the rows whose load-point travel lies within
    ``share`` of the travel at the peak either side of each row (the peak found first with
    ``share`` of the whole travel). History rows sample the force; a
    run rings (the lever's load of a mixed-mode test rang at 8 kHz once its first cohesive
    elements failed, the rows every 0.1 ms: the same run's largest row read 1.02 to 1.09 of
    the initiation load by where the rows fell), and the largest row is then where a swing
    fell. A quasi-static force is flat at its peak, so the mean over a small share of the
    travel leaves it; at a corner of the theory, a straight rise and a falling branch, it
    takes off up to half the share's worth of the slopes (0.25-0.5 % at 1 %; a sudden drop,
    up to 1 %). Rows sparser than the share are not averaged. ``displacement``: the load
    point's (mm, either sign; a driven load point's, which does not go back). Raises
    ValueError for no rows, rows of unequal length or values that are not finite."""
    travel = np.abs(np.asarray(displacement, dtype=float))
    force = np.asarray(force, dtype=float)
    if len(force) == 0 or travel.shape != force.shape:
        raise ValueError(
            f"averaged_peak: {len(travel)} displacements and {len(force)} forces: one of "
            "each per row, at least one row"
        )
    if not (np.isfinite(travel).all() and np.isfinite(force).all()):
        raise ValueError("averaged_peak: a displacement or force is not finite")
    travel = np.maximum.accumulate(travel)  # (round-off going back: sorted for the search)
    total = np.concatenate([[0.0], np.cumsum(force)])

    def means(reach: float) -> np.ndarray:  # over the rows [lo, hi) within reach of each row
        lo = np.searchsorted(travel, travel - reach, side="left")
        hi = np.searchsorted(travel, travel + reach, side="right")
        return (total[hi] - total[lo]) / (hi - lo)

    # where the peak is, averaged over the share of the whole travel (a lone early spike is
    # averaged with its neighbours there), then the share of the travel at that peak
    at = int(np.argmax(means(share * travel[-1])))
    return float(means(share * travel[at]).max())


def against_theory(history: dict, displacement, force, theory, initiation: float, crack,
                   branch_start: float, branch_end: float, Gc: float, work,
                   bin_width: float) -> dict:  # fmt: skip
    """What a fracture test's run shows against its theory, the part DCB and ENF share.

    Parameters:
        history: the run's history columns (``crack_growth_area``, ``cohesive_dissipation``,
            ``kinetic_energy``).
        displacement, force: the load point's displacement (mm) and force (N) per row.
        theory: the theory's force (N) at each row's displacement.
        initiation: the theory's initiation force (N).
        crack: the crack length (mm) per row.
        branch_start, branch_end: the crack lengths (mm) that bound the propagation branch.
        Gc: the fracture energy (N/mm) the dissipation is measured against.
        work: the work put in (mJ) per row.
        bin_width: the crack-length bins (mm) of the branch.

    Returns:
        ``initiation_force_N``, ``peak_force_N``, ``peak_over_initiation`` (the largest row),
        ``peak_averaged_force_N`` and ``peak_averaged_over_initiation`` (``averaged_peak``:
        the rows' ringing averaged out), ``initial_stiffness_N_per_mm`` (the slope while
        nothing grew, between 5 % and 50 % of the initiation force),
        ``crack_length_range_mm``, ``branch_points``, the force over the theory's on the
        branch (``force_over_theory_mean``, ``_min``, ``_max``, ``_bins``),
        ``dissipation_rate_over_Gc`` (the slope of the cohesive dissipation against the grown
        area, over Gc) and ``kinetic_energy_share`` (the largest kinetic energy over the work
        put in, once that is 1 % of its final value).
    """
    displacement, force, theory = (np.asarray(v, dtype=float) for v in (displacement, force,
                                                                          theory))  # fmt: skip
    grown = np.asarray(history["crack_growth_area"])
    crack = np.asarray(crack, dtype=float)
    elastic = (grown == 0.0) & (force > 0.05 * initiation) & (force < 0.5 * initiation)
    stiffness = (
        float(np.polyfit(displacement[elastic], force[elastic], 1)[0])
        if elastic.sum() > 1
        else None
    )
    on_branch = (crack > branch_start) & (crack < branch_end)
    ratio = force[on_branch] / theory[on_branch]
    bins = {}
    for low in np.arange(branch_start, min(crack.max(), branch_end), bin_width):
        chosen = on_branch & (crack >= low) & (crack < low + bin_width)
        if chosen.any():
            bins[f"{low:.1f}-{low + bin_width:.1f}"] = float(np.mean(ratio[chosen[on_branch]]))
    growing = grown > 0.0
    dissipation = np.asarray(history["cohesive_dissipation"])
    rate = (
        float(np.polyfit(grown[growing], dissipation[growing], 1)[0] / Gc)
        if len(np.unique(grown[growing])) > 1
        else None
    )
    work = np.asarray(work)
    loaded = work > 0.01 * work.max() if work.max() > 0 else np.zeros(len(work), bool)
    kinetic = np.asarray(history["kinetic_energy"])
    averaged = averaged_peak(displacement, force)
    return {
        "initiation_force_N": initiation,
        "peak_force_N": float(force.max()),
        "peak_over_initiation": float(force.max() / initiation),
        "peak_averaged_force_N": averaged,
        "peak_averaged_over_initiation": averaged / initiation,
        "initial_stiffness_N_per_mm": stiffness,
        "crack_length_range_mm": [float(crack.min()), float(crack.max())],
        "branch_points": int(on_branch.sum()),
        "force_over_theory_mean": float(ratio.mean()) if on_branch.any() else None,
        "force_over_theory_min": float(ratio.min()) if on_branch.any() else None,
        "force_over_theory_max": float(ratio.max()) if on_branch.any() else None,
        "force_over_theory_bins": bins,
        "dissipation_rate_over_Gc": rate,
        "kinetic_energy_share": float((kinetic[loaded] / work[loaded]).max())
        if loaded.any()
        else None,
    }


def dcb_comparison(config: RunConfig, history: dict, bin_width: float = 5.0) -> dict:
    """A DCB run against corrected beam theory (``dcb_force``). The specimen: two equal arms
    above and below the interface of its first insert film ([[delamination]]), which reaches
    the load line at x = length; the history's ``displacement`` is the top arm's load-line
    displacement (the opening is twice it) and ``reaction_force`` the force on it.

    Parameters:
        config: the run's config.
        history: its history columns (``io.output.read_history``).
        bin_width: the crack-length bins (mm) of the propagation branch.

    Returns:
        The initial crack ``a0_mm`` and its root-rotation correction ``chi`` (x arm thickness),
        ``initiation_force_N`` (analytic, effective crack a0 + chi h) against ``peak_force_N``;
        ``initial_stiffness_N_per_mm`` against corrected beam theory's; on the propagation
        branch (crack longer than a0 + 5 arm thicknesses): the run's force over the theory's,
        mean, min, max and per ``bin_width`` bin; ``dissipation_rate_over_Gc``: the slope of
        the cohesive dissipation against the grown area, over GIc; ``kinetic_energy_share``:
        the largest kinetic energy over the work put in (once that is 1 % of its final value).

    Raises:
        ValueError: no insert film, or arms of unequal thickness.
    """
    if not config.delaminations:
        raise ValueError("dcb_comparison: the config has no insert film ([[delamination]])")
    film = config.delaminations[0]
    arm = arm_thickness(config.laminate, film.interface)
    if abs(arm - (config.laminate.thickness - arm)) > 1e-9 * arm:
        raise ValueError(f"dcb_comparison: the arms are {arm:g} and "
                         f"{config.laminate.thickness - arm:g} mm thick, not equal")  # fmt: skip
    width, GIc = config.mesh.width, config.cohesive.GIc
    material = arm_moduli(config.laminate, film.interface, width)
    a0 = config.mesh.length - film.region.x_min
    chi = root_rotation_correction(material)
    effective = a0 + chi * arm
    opening = 2.0 * np.asarray(history["displacement"])
    force = np.asarray(history["reaction_force"])
    grown = np.asarray(history["crack_growth_area"])
    theory = dcb_force(opening, material.E1, width, arm, GIc, effective)
    initiation = dcb_initiation_force(material.E1, width, arm, GIc, effective)
    EI = material.E1 * width * arm**3 / 12.0
    return {
        "a0_mm": a0,
        "chi": chi,
        "arm_thickness_mm": arm,
        **against_theory(
            history, opening, force, theory, initiation, a0 + grown / width, a0 + 5.0 * arm,
            np.inf, GIc, history["external_work"], bin_width,
        ),
        "theory_stiffness_N_per_mm": 3.0 * EI / (2.0 * effective**3),
    }  # fmt: skip


# ------------------------------------------------------------------ end-notched flexure (ENF)
def enf_compliance(crack, half_span: float, modulus: float, shear_modulus: float, width: float,
                   arm: float):  # fmt: skip
    """Load-point compliance (mm/N) of an end-notched flexure beam (three-point bending, span
    2 L, nose at mid-span, crack of length ``crack`` a (mm) from a support): the bending of
    ASTM D7905's beam theory, (2 L^3 + 3 a^3) / (8 E b h^3), plus Timoshenko's shear of the
    whole beam, 3 L / (10 G b h) (``arm``: h, half the thickness). No crack-tip correction
    (Wang and Williams' a + 0.42 chi h): the static FE compliance of an earlier version of
    demos/fracture_tests_enf.toml (L = 60 mm, a0 = 45 mm, 5 mm rollers; ``fenics-adaptive
    static``, 0.9 mm at the nose) is this one's to 0.02 %, and 2.8 % below the corrected one;
    the explicit runs of the L = 80 mm beam start at 0.994 of this one's stiffness."""
    crack = np.asarray(crack, dtype=float)
    bending = (2.0 * half_span**3 + 3.0 * crack**3) / (8.0 * modulus * width * arm**3)
    return bending + 3.0 * half_span / (10.0 * shear_modulus * width * arm)


def enf_propagation_force(crack, modulus: float, width: float, arm: float, GIIc: float):
    """The force (N) at which an ENF beam with the crack ``crack`` (mm) reaches
    GIIc: G_II = 9 P^2 a^2 / (16 E b^2 h^3) (the shear term does not depend on a)."""
    return 4.0 * width * np.sqrt(modulus * arm**3 * GIIc) / (3.0 * np.asarray(crack, float))


def enf_force(displacement, half_span: float, a0: float, modulus: float, shear_modulus: float,
              width: float, arm: float, GIIc: float) -> np.ndarray:  # fmt: skip
    """Force (N) of an ENF beam against its load point's displacement (mm, any shape) by beam
    theory (``enf_compliance``): the elastic line of the crack a0 until the force reaches
    ``enf_propagation_force``, then the propagation branch, traced by the crack length from a0
    to the nose (L); where growth is unstable (a0 < L / 3^(1/3) in bending) the branch is the
    lower envelope the force drops to."""
    return branch_force(
        displacement, a0, half_span,
        lambda crack: enf_compliance(crack, half_span, modulus, shear_modulus, width, arm),
        lambda crack: enf_propagation_force(crack, modulus, width, arm, GIIc),
    )  # fmt: skip


CRACKS_ON_BRANCH = 400  # crack lengths a branch is traced by


def branch_force(displacement, a0: float, half_span: float, compliance, propagation):
    """Force (N) of a beam test against its load point's displacement (mm, any shape) by a
    beam theory given as ``compliance(crack)`` (mm/N) and ``propagation(crack)`` (N, the load
    at which the crack grows): the elastic line of the crack a0 until the force reaches the
    propagation force, then the branch traced by the crack from a0 to the load point at
    ``half_span`` (mm); where growth is unstable, the lower envelope the force drops to."""
    cracks = np.linspace(a0, half_span, CRACKS_ON_BRANCH)
    force = propagation(cracks)
    travel = compliance(cracks) * force
    displacement = np.asarray(displacement, dtype=float)
    elastic = displacement / compliance(a0)
    order = np.argsort(travel)
    return np.minimum(elastic, np.interp(displacement, travel[order], force[order]))


def against_bending_theory(history: dict, load: str, a0: float, half_span: float, arm: float,
                           width: float, compliance, propagation, Gc: float,
                           bin_width: float) -> dict:  # fmt: skip
    """What a three-point-bending fracture test's run (ENF, MMB) shows against its beam
    theory (``compliance``, ``propagation`` as ``branch_force`` takes them): the load and the
    load point's displacement are the history's ``<load>_force`` and ``<load>_displacement``
    (down is negative); the crack grows from a0 (mm) towards the load point at ``half_span``;
    the branch is judged from a0 + 5 arm thicknesses to one arm thickness short of the load
    point; ``Gc`` (N/mm) is what the dissipation is measured against.

    Returns:
        ``a0_mm``, ``half_span_mm``, ``arm_thickness_mm``, ``stable_growth`` (the theory's
        load-point displacement grows with the crack), what ``against_theory`` returns, and
        ``theory_stiffness_N_per_mm``.
    """
    displacement = -np.asarray(history[f"{load}_displacement"])
    force = np.asarray(history[f"{load}_force"])
    crack = a0 + np.asarray(history["crack_growth_area"]) / width
    theory = branch_force(displacement, a0, half_span, compliance, propagation)
    cracks = np.linspace(a0, half_span, CRACKS_ON_BRANCH)
    branch_displacement = compliance(cracks) * propagation(cracks)
    return {
        "a0_mm": a0,
        "half_span_mm": half_span,
        "arm_thickness_mm": arm,
        "stable_growth": bool(np.all(np.diff(branch_displacement) > 0.0)),
        **against_theory(
            history, displacement, force, theory, float(propagation(a0)), crack,
            a0 + 5.0 * arm, half_span - arm, Gc, history["impact_work"], bin_width,
        ),
        "theory_stiffness_N_per_mm": float(1.0 / compliance(a0)),
    }  # fmt: skip


def enf_comparison(config: RunConfig, history: dict, bin_width: float = 5.0) -> dict:
    """An ENF run against corrected beam theory. The specimen: two equal arms above and below
    the interface of its first insert film, which reaches the end x = length past the right
    support; two rigid supports ([[rigid]] "left" and "right", on the bottom face) and a rigid
    nose ("nose", top face, half-way). The history's ``nose_force`` and ``nose_displacement``
    are the load and the load-point displacement.

    Parameters:
        config: the run's config.
        history: its history columns (``io.output.read_history``).
        bin_width: the crack-length bins (mm) of the propagation branch.

    Returns:
        As ``dcb_comparison``: ``a0_mm`` (from the right support),
        ``initiation_force_N`` against ``peak_force_N``,
        ``initial_stiffness_N_per_mm`` against ``theory_stiffness_N_per_mm``; on the
        propagation branch (crack beyond a0 + 5 h, short of the nose by h) the force over the
        theory's at the run's displacement (mean, min, max, per bin);
        ``dissipation_rate_over_Gc`` (Gc = GIIc); ``kinetic_energy_share``.
    """
    film = config.delaminations[0]
    bodies = {body.name: body for body in config.rigid_bodies}
    support, nose = bodies["right"].position[0], bodies["nose"].position[0]
    half_span = support - nose
    arm = arm_thickness(config.laminate, film.interface)
    width, GIIc = config.mesh.width, config.cohesive.GIIc
    material = arm_moduli(config.laminate, film.interface, width)
    a0 = support - film.region.x_min

    def compliance(crack):
        return enf_compliance(crack, half_span, material.E1, material.G12, width, arm)

    def propagation(crack):
        return enf_propagation_force(crack, material.E1, width, arm, GIIc)

    return against_bending_theory(history, "nose", a0, half_span, arm, width, compliance,
                                  propagation, GIIc, bin_width)  # fmt: skip


# -------------------------------------------------------------------- mixed-mode bending (MMB)
def mmb_load_split(load_arm: float, half_span: float) -> tuple[float, float]:
    """The lever load P of an MMB test split into its modes (Reeder and Crews 1990): the mode I
    pair P_I = P (3c - L) / (4L) opening the arms' ends and the mode II load P_II = P (c + L) / L
    at mid-span of an ENF beam. Returns (P_I / P, P_II / P) for the lever's load arm c and the
    half-span L (mm)."""
    return (3.0 * load_arm - half_span) / (4.0 * half_span), (load_arm + half_span) / half_span


def mmb_load_arm(mixity: float, half_span: float) -> float:
    """The load arm c (mm) that gives the mode mixity G_II / G = ``mixity`` (0 < mixity < 1) by
    simple beam theory, where G_I / G_II = 4 (3c - L)^2 / (3 (c + L)^2) does not depend on the
    crack: c = L (1 + k) / (3 - k), k = sqrt(3 (1 - mixity) / (4 mixity)) (the branch with
    3c > L, the arms pulled open). The corrected theory's mixity (``mmb_energy_release``)
    differs from it by the root-rotation correction of mode I."""
    if not 0.0 < mixity < 1.0:
        raise ValueError(f"mmb_load_arm: the mixity G_II / G must lie in (0, 1) (got {mixity})")
    k = np.sqrt(3.0 * (1.0 - mixity) / (4.0 * mixity))
    if k >= 3.0:
        raise ValueError(f"mmb_load_arm: G_II / G = {mixity} is below what a lever gives (1/13)")
    return float(half_span * (1.0 + k) / (3.0 - k))


def mmb_energy_release(crack, load_arm: float, half_span: float, modulus: float, width: float,
                       arm: float, chi: float):  # fmt: skip
    """The energy release rates per squared lever load, G_I / P^2 and G_II / P^2 (N/mm per
    N^2), of an MMB beam with the crack ``crack`` a (mm): the DCB's P_I^2 (a + chi h)^2 /
    (b E I) (corrected for root rotation) and the ENF's 9 P_II^2 a^2 / (16 E b^2 h^3)
    (``enf_propagation_force``'s, uncorrected), E I = E1 b h^3 / 12 of one arm (thickness h)."""
    crack = np.asarray(crack, dtype=float)
    mode_I, mode_II = mmb_load_split(load_arm, half_span)
    EI = modulus * width * arm**3 / 12.0
    g_I = mode_I**2 * (crack + chi * arm) ** 2 / (width * EI)
    g_II = mode_II**2 * 9.0 * crack**2 / (16.0 * modulus * width**2 * arm**3)
    return g_I, g_II


def mmb_compliance(crack, load_arm: float, half_span: float, modulus: float,
                   shear_modulus: float, width: float, arm: float, chi: float):  # fmt: skip
    """Load-point compliance (mm/N) of an MMB beam by superposition: the lever's load point
    moves (P_I/P) times the DCB's opening plus (P_II/P) times the ENF's mid-span deflection,
    C = (P_I/P)^2 2 (a + chi h)^3 / (3 E I) + (P_II/P)^2 C_ENF(a) (``enf_compliance``)."""
    crack = np.asarray(crack, dtype=float)
    mode_I, mode_II = mmb_load_split(load_arm, half_span)
    EI = modulus * width * arm**3 / 12.0
    dcb = 2.0 * (crack + chi * arm) ** 3 / (3.0 * EI)
    enf = enf_compliance(crack, half_span, modulus, shear_modulus, width, arm)
    return mode_I**2 * dcb + mode_II**2 * enf


def mmb_propagation_force(crack, load_arm: float, half_span: float, modulus: float,
                          width: float, arm: float, chi: float, law) -> np.ndarray:  # fmt: skip
    """The lever load (N) at which an MMB beam with the crack ``crack`` (mm) reaches its
    fracture energy G_c(G_II / G) of the mixed-mode ``law`` (a ``CohesiveLaw``:
    ``materials.cohesive.critical_energy``) at the mixity of ``mmb_energy_release``."""
    g_I, g_II = mmb_energy_release(crack, load_arm, half_span, modulus, width, arm, chi)
    mixity = g_II / (g_I + g_II)
    Gc = np.vectorize(lambda b: critical_energy(law, float(b)))(mixity)
    return np.sqrt(Gc / (g_I + g_II))


def mmb_force(displacement, load_arm: float, half_span: float, a0: float, modulus: float,
              shear_modulus: float, width: float, arm: float, chi: float,
              law) -> np.ndarray:  # fmt: skip
    """Lever load (N) of an MMB beam against its load point's displacement (mm, any shape):
    the elastic line of the crack a0 (``mmb_compliance``) until the load reaches
    ``mmb_propagation_force``, then the propagation branch traced by the crack from a0 to the
    saddle (L), its lower envelope where growth is unstable."""
    beam = (modulus, shear_modulus, width, arm, chi)
    return branch_force(
        displacement, a0, half_span,
        lambda crack: mmb_compliance(crack, load_arm, half_span, *beam),
        lambda crack: mmb_propagation_force(crack, load_arm, half_span, modulus, width, arm,
                                            chi, law),
    )  # fmt: skip


def hinge_position(config: RunConfig) -> float:
    """x (mm) of an MMB lever's hinge: the end (x0 or x1) its node line names.

    Raises:
        ValueError: no lever, or a hinge at neither end."""
    if config.lever is None:
        raise ValueError("the config has no [lever]")
    faces = config.lever.hinge.split("&")
    if "x1" in faces:
        return config.mesh.length
    if "x0" in faces:
        return 0.0
    raise ValueError(f"the lever's hinge {config.lever.hinge!r} is at neither end (x0, x1)")


@dataclass(frozen=True)
class MMBSpecimen:
    """The beam-theory data of an MMB config: two equal arms above and below the interface of
    its first insert film, which reaches the end of the lever's hinge; the lever's saddle at
    mid-span. Lengths in mm, moduli in MPa."""

    a0: float  # the film's length from the hinge
    half_span: float  # L: hinge to saddle
    load_arm: float  # c: saddle to load point
    arm: float  # h: one arm's thickness
    width: float
    material: ArmModuli  # the arms' (``arm_moduli``)
    chi: float  # root-rotation correction (``root_rotation_correction``)
    law: CohesiveLaw

    @classmethod
    def of(cls, config: RunConfig) -> MMBSpecimen:
        film = config.delaminations[0]
        hinge = hinge_position(config)
        saddle = next(b for b in config.rigid_bodies if b.name == config.lever.saddle)
        material = arm_moduli(config.laminate, film.interface, config.mesh.width)
        return cls(
            a0=hinge - film.region.x_min if hinge > 0.0 else film.region.x_max,
            half_span=abs(saddle.position[0] - hinge),
            load_arm=config.lever.load_arm,
            arm=arm_thickness(config.laminate, film.interface),
            width=config.mesh.width,
            material=material,
            chi=root_rotation_correction(material),
            law=config.cohesive,
        )

    def compliance(self, crack, load_arm: float | None = None):
        """``mmb_compliance`` (mm/N) of this beam, with its lever arm or ``load_arm``."""
        c, m = self.load_arm if load_arm is None else load_arm, self.material
        return mmb_compliance(crack, c, self.half_span, m.E1, m.G12, self.width, self.arm,
                              self.chi)  # fmt: skip

    def propagation(self, crack, load_arm: float | None = None):
        """``mmb_propagation_force`` (N) of this beam, with its lever arm or ``load_arm``."""
        return mmb_propagation_force(crack, self.load_arm if load_arm is None else load_arm,
                                     self.half_span, self.material.E1, self.width, self.arm,
                                     self.chi, self.law)  # fmt: skip

    def mixity(self, crack) -> float:
        """G_II / G of the theory at the crack ``crack`` (mm)."""
        g_I, g_II = mmb_energy_release(crack, self.load_arm, self.half_span, self.material.E1,
                                       self.width, self.arm, self.chi)  # fmt: skip
        return float(g_II / (g_I + g_II))


def mmb_comparison(config: RunConfig, history: dict, bin_width: float = 5.0) -> dict:
    """An MMB run against corrected beam theory (``mmb_force``). The specimen:
    ``MMBSpecimen``. The history's ``lever_force`` and ``lever_displacement`` are the load and
    the load point's displacement (down is negative).

    Parameters:
        config: the run's config.
        history: its history columns (``io.output.read_history``).
        bin_width: the crack-length bins (mm) of the propagation branch.

    Returns:
        As ``enf_comparison``, with ``load_arm_mm`` c, ``chi``, ``mixity`` (G_II / G of the
        theory at a0) and ``Gc_N_per_mm`` (the fracture energy at that mixity, which the
        dissipation is measured against).
    """
    beam = MMBSpecimen.of(config)
    mixity = beam.mixity(beam.a0)
    Gc = critical_energy(beam.law, mixity)
    return {
        **against_bending_theory(history, "lever", beam.a0, beam.half_span, beam.arm,
                                 beam.width, beam.compliance, beam.propagation, Gc,
                                 bin_width),
        "load_arm_mm": beam.load_arm,
        "chi": beam.chi,
        "mixity": mixity,
        "Gc_N_per_mm": Gc,
    }  # fmt: skip
