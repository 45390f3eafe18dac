"""Beam-theory LEFM reference of a cantilever-beam delamination test (DCB, TCB): the force on
the propagation branch, and a run's history compared with it.

Units: N, mm, s, tonne (force N, opening mm, fracture energy N/mm, modulus MPa).

Each arm is a cantilever of bending stiffness E I = E1 b h^3 / 12 (width b, thickness h) pulled
open by delta at its end. Eliminating the crack length between the arm's compliance and the
energy release rate at G = GIc gives the propagation branch P = K^1.5 / sqrt(3 E I delta),
K = sqrt(2 b E I GIc). The same branch follows from root-rotation-corrected beam theory
(Hashemi 1990), which writes the compliance and G with one effective length a + chi h;
``root_rotation_correction`` gives chi for the record.
"""

from __future__ import annotations

import numpy as np

from fenics_adaptive.materials.laminate import Laminate, PlyMaterial
from fenics_adaptive.settings.config import RunConfig

SMALLEST_OPENING = 1e-12  # mm: the branch is infinite at delta = 0


def arm_thickness(laminate: Laminate, interface: int) -> float:
    """Thickness (mm) of the arm above ply interface ``interface`` (between ply ``interface``
    and ply ``interface + 1``, counted from 1 at the bottom): the plies above it."""
    return sum(p.thickness for p in laminate.plies[interface:])


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


def root_rotation_correction(material: PlyMaterial) -> float:
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
