"""Bilinear mixed-mode cohesive law and the 8-node cohesive element (LS-DYNA *MAT_138 style).

Units: N, mm, s, tonne. Penalty stiffnesses K_n, K_s in N/mm^3 (traction per opening), strengths
N, S in MPa, fracture energies GIc, GIIc in N/mm (= mJ/mm^2), openings in mm, energy densities
in N/mm, element energies in mJ (N mm).

The law (Camanho & Davila 2002, as in LS-DYNA *MAT_COHESIVE_MIXED_MODE, with separate normal and
shear penalties). The local opening is delta = (d1, d2, d3): d1, d2 tangential, d3 normal.

    delta_I  = <d3> = max(d3, 0)            delta_II = sqrt(d1^2 + d2^2)
    delta_m  = sqrt(delta_I^2 + delta_II^2)  beta     = delta_II / delta_I

Onset (quadratic traction criterion (t_n/N)^2 + (t_s/S)^2 = 1 reached along the current path):

    dI0 = N / K_n,   dII0 = S / K_s
    d0  = dI0 dII0 sqrt((1 + beta^2) / (dII0^2 + (beta dI0)^2)),   d0 = dII0 if delta_I = 0

Along a proportional path the effective stiffness and the mode mixity are

    K_m = (K_n + beta^2 K_s) / (1 + beta^2)
    B   = G_II / (G_I + G_II) = beta^2 K_s / (K_n + beta^2 K_s)

and the final opening follows from the critical energy release rate G_c(B):

    Benzeggagh-Kenane ("bk", exponent eta):  G_c = GIc + (GIIc - GIc) B^eta
    power law ("power", exponent alpha):     G_c = [((1-B)/GIc)^alpha + (B/GIIc)^alpha]^(-1/alpha)
    dF = 2 G_c / (K_m d0)

For "power" this is LS-DYNA's form
    dF = 2 (1+beta^2)/d0 [(K_n/GIc)^alpha + (K_s beta^2/GIIc)^alpha]^(-1/alpha).
With K_n = K_s = K, B = beta^2/(1+beta^2) and these reduce to DESIGN.md's formulas. Pure shear
(or shear under compression) gives dF = 2 GIIc / (K_s dII0) for both laws. The kernel evaluates
everything in terms of delta_I^2 and delta_II^2 rather than beta, so that delta_I -> 0 needs no
special case and beta^2 cannot overflow. G_c(B) is ``critical_energy``: the energy per unit area
dissipated to full separation on a proportional path, 1/2 K_m d0 dF.

Damage (one scalar per integration point, never decreasing):

    d = clip(dF (delta_m - d0) / (delta_m (dF - d0)), 0, 1),   d = max(d_old, d)

Tractions: t_i = (1 - d) K_s d_i (i = 1, 2); t_3 = (1 - d) K_n d3 if d3 > 0, else
phi K_n d3 (compression is never damaged). phi = 1 but at a broken point (d = 1) whose faces
have slid by more than half the element's size or passed a tenth of it into each other: it
then lets go of its contact, smoothly, down to nothing at a slip of the element's size or a
depth of a fifth of it (``pressed_share``), and for good (phi the smallest share it has had;
the energy it lets go of is dissipated, booked as the damage's): beyond that a pressed jump
no longer says where the faces are, and a broken interface of a perforated plate is left to
its open faces. On a proportional path the effective traction K_m delta_m (1 - d) rises
linearly to K_m d0 and falls linearly to zero at dF: the area under it is G_c. Unloading goes
back to the origin along the damaged secant (1 - d) K. The recoverable (stored) energy
density is

    psi = 1/2 (1 - d) (K_s (d1^2 + d2^2) + K_n <d3>^2) + 1/2 phi K_n <-d3>^2

so that the dissipated energy is the external work minus psi.

Dissipation from the law's own increments. A secant law k(d) (k = (1 - d) K per damaged opening
component) under the trapezoidal work of the solver, W = 1/2 (t_n + t_{n+1}) (x_{n+1} - x_n),
stores psi = 1/2 k x^2, so the work not stored over a step is exactly

    W - (psi_{n+1} - psi_n) = 1/2 (k_n - k_{n+1}) x_n x_{n+1} = 1/2 K (d_{n+1} - d_n) x_n x_{n+1}

per component: the dissipation increment dD = 1/2 K delta^2 dd in its consistent (geometric
mean) form, summed over the tangential components and the normal one while open at both
calls. ``cohesive_element_force_tracked`` accumulates it per Gauss point (times the point's
reference area); summed to full separation along a proportional path it is G_c per area.

The element. Eight nodes: 0-3 the lower face, 4-7 the upper face, coincident in the reference
configuration. Within a face, node a sits at face coordinates (a & 1, (a >> 1) & 1) on [0, 1]^2
(tensor order: 0=(0,0), 1=(1,0), 2=(0,1), 3=(1,1)), with bilinear shape functions. 2 x 2 Gauss
points (0.5 -+ 0.5/sqrt(3), weight 1/4 each), numbered the same way as the nodes; ``damage[k]``
is the history of point k. At each point the local frame follows the current mid-surface
x_mid = X + (u_lower + u_upper)/2: t1 = dx_mid/dxi normalised, n = t1' x t2' normalised
(t1', t2' the two tangents), t2 = n x t1. The jump u_upper - u_lower is projected on (t1, t2, n)
to give delta. Tractions are nominal: they are integrated over the REFERENCE mid-surface area.
The force is the gradient of the element's energy sum_k psi_k dA_k, the frame's turning
included: psi depends on how the jump splits into normal and tangential parts once the
interface is damaged or pressed closed (or K_n != K_s), so a frame that turns with the
mid-surface changes psi by -w.(delta x t) (w its rotation, in local axes) with the jump held.
Without that term a broken, pressed interface whose faces tumble (a perforated plate) is a
non-conservative force that gave energy to the run.

Force sign (paper Eq. 3, f_int = f_lam - f_coh): ``f_coh`` is the force the tractions apply to the
nodes, -N_a T dA on upper node a + 4 and +N_a T dA on lower node a (T the traction in global
coordinates). An opened interface thus pulls the upper face down and the lower face up.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fenics_adaptive.settings.kinds import MixedModeLaw
from fenics_adaptive.settings.materials import (
    LAW_BK,
    P_EXPONENT,
    P_GIC,
    P_GIIC,
    P_KN,
    P_KS,
    P_LAW,
    P_N,
    P_S,
    CohesiveLaw,
)

# Columns of a cohesive point's history (cohesive_element_force_tracked): the local opening of
# the last call, the energy the point has dissipated (mJ), and the share of its contact penalty
# a broken point has let go of (``pressed_share``: 0 while it holds all of it).
H_D1, H_D2, H_D3, H_DISSIPATED, H_RELEASED = range(5)
HISTORY = 5


def critical_energy(law: CohesiveLaw, mixity: float) -> float:
    """Energy per unit area (N/mm) dissipated to full separation along a proportional path of
    mode mixity B = G_II / (G_I + G_II) in [0, 1]; equals 1/2 K_m d0 dF."""
    if not 0.0 <= mixity <= 1.0:
        raise ValueError(f"mixity must lie in [0, 1] (got {mixity})")
    if law.law == MixedModeLaw.BK:
        return law.GIc + (law.GIIc - law.GIc) * mixity**law.exponent
    a = law.exponent
    return (((1.0 - mixity) / law.GIc) ** a + (mixity / law.GIIc) ** a) ** (-1.0 / a)


def cohesive_zone_length(law: CohesiveLaw, transverse_modulus: float, M: float = 1.0) -> float:
    """Length (mm) of a fully developed process zone of ``law`` in a body of transverse (through-
    thickness) modulus ``transverse_modulus`` (MPa): Turon et al. (2007, Eng. Fract. Mech. 74,
    1665), l_cz = M E G_c / tau0^2, the longer of mode I (GIc, N) and mode II (GIIc, S), since a
    delamination's mode is not known before it grows. M = 1 is Hillerborg's estimate; the
    zone of a slender arm is shorter (Yang and Cox 2005), so this length errs on the long side.
    """
    if transverse_modulus <= 0.0 or M <= 0.0:
        raise ValueError(f"modulus and M must be > 0 (got {transverse_modulus}, {M})")
    mode_i = law.GIc / law.N**2
    mode_ii = law.GIIc / law.S**2
    return M * transverse_modulus * max(mode_i, mode_ii)


@njit(cache=True, inline="always")
def _fade(x, start, stop):
    """The smooth (C1) step from 1 at x <= start to 0 at x >= stop."""
    if x <= start:
        return 1.0
    if x >= stop:
        return 0.0
    t = (x - start) / (stop - start)
    return 1.0 - t * t * (3.0 - 2.0 * t)


@njit(cache=True, inline="always")
def pressed_share(slip, depth, size):
    """The share of its contact penalty that a broken point pressed closed by ``depth`` (mm,
    -d3 > 0) may keep after its faces slid by ``slip`` (mm), in an element of in-plane size
    ``size`` (mm): all of it up to a slip of size / 2 and a depth of size / 10, none from a
    slip of ``size`` or a depth of size / 5 (smooth steps between, their product). The point
    keeps the smallest share it has had (what it lets go of is gone, its energy dissipated:
    ``_element_force``). The penalty keeps the faces of a broken interface apart while each
    still faces its partner; once they have slid by about an element, or passed through each
    other, the jump's normal part no longer says where the faces are (a perforated plate's
    broken interfaces slid by up to 7 mm in 0.6 mm cells and were read as pressed, then as
    pressed 1.6 mm deep once faces had passed through: 160 GPa, and the run exploded). A
    contact search would find the faces that do touch; LS-DYNA's contacts release a node
    pressed deeper than a set depth likewise, and its and Abaqus's cohesive elements go once
    broken. A broken point presses K_n size / 10 (6 GPa for K_n = 1e5 N/mm^3 in 0.6 mm cells)
    before its share drops; an intact or damaged one keeps all of it."""
    return _fade(slip, 0.5 * size, size) * _fade(depth, 0.1 * size, 0.2 * size)


@njit(cache=True)
def _law(d1, d2, d3, params, damage_old, share):
    """Scalar kernel: returns (t1, t2, t3, damage_new, stored_energy_density). ``share``: of
    the contact penalty, for a pressed point (1 but for broken points, ``pressed_share``)."""
    K_n, K_s = params[P_KN], params[P_KS]
    sI2 = d3 * d3 if d3 > 0.0 else 0.0  # delta_I^2
    sII2 = d1 * d1 + d2 * d2  # delta_II^2
    dm2 = sI2 + sII2
    damage = damage_old
    if dm2 > 0.0:
        dm = math.sqrt(dm2)
        dI0 = params[P_N] / K_n
        dII0 = params[P_S] / K_s
        # d0 with beta^2 = sII2/sI2 multiplied through by sI2 (valid for sI2 = 0 too).
        d0 = dI0 * dII0 * math.sqrt(dm2 / (dII0 * dII0 * sI2 + dI0 * dI0 * sII2))
        if dm > d0:
            gI = K_n * sI2  # proportional to G_I on this path
            gII = K_s * sII2  # proportional to G_II
            B = gII / (gI + gII)
            K_m = (gI + gII) / dm2
            GIc, GIIc, p = params[P_GIC], params[P_GIIC], params[P_EXPONENT]
            if params[P_LAW] == LAW_BK:
                Gc = GIc + (GIIc - GIc) * B**p
            else:
                Gc = ((gI / (gI + gII) / GIc) ** p + (B / GIIc) ** p) ** (-1.0 / p)
            dF = 2.0 * Gc / (K_m * d0)
            if dm >= dF:  # also covers dF <= d0 (instant failure)
                d_new = 1.0
            else:
                d_new = dF * (dm - d0) / (dm * (dF - d0))
            if d_new > damage:
                damage = d_new
    s = 1.0 - damage
    t1 = s * K_s * d1
    t2 = s * K_s * d2
    psi = 0.5 * s * (K_s * sII2 + K_n * sI2)
    if d3 > 0.0:
        t3 = s * K_n * d3
    else:
        t3 = share * K_n * d3
        psi += 0.5 * share * K_n * d3 * d3
    return t1, t2, t3, damage, psi


@njit(cache=True)
def cohesive_traction(
    delta: np.ndarray, params: np.ndarray, damage_old: float
) -> tuple[np.ndarray, float, float]:
    """Traction (3,) in the local frame, new damage and stored energy density for the local
    opening ``delta`` = (d1, d2, d3) and the point's previous damage."""
    t1, t2, t3, damage, psi = _law(delta[0], delta[1], delta[2], params, damage_old, 1.0)
    traction = np.empty(3)
    traction[0] = t1
    traction[1] = t2
    traction[2] = t3
    return traction, damage, psi


@njit(cache=True, inline="always", error_model="numpy")
def _element_force(X, u, params, damage, history, track, f_coh):
    """``cohesive_element_force``; with ``track`` also the dissipation of each point into
    ``history`` (4, HISTORY) (``cohesive_element_force_tracked``). Vectors are scalar
    triples: the kernel allocates nothing (a dozen small arrays per element were most of its
    time)."""
    g = 0.5 / math.sqrt(3.0)
    f_coh[:, :] = 0.0
    # in-plane size: the square root of the reference area of the lower face (the faces
    # coincide in the reference; half the cross product of the diagonals 0-3 and 1-2, exact
    # for a plane face)
    e0, e1, e2 = X[3, 0] - X[0, 0], X[3, 1] - X[0, 1], X[3, 2] - X[0, 2]
    h0, h1, h2 = X[2, 0] - X[1, 0], X[2, 1] - X[1, 1], X[2, 2] - X[1, 2]
    size = math.sqrt(
        0.5
        * math.sqrt((e1 * h2 - e2 * h1) ** 2 + (e2 * h0 - e0 * h2) ** 2 + (e0 * h1 - e1 * h0) ** 2)
    )
    energy = 0.0
    area = 0.0
    for k in range(4):
        xi = 0.5 + g if k & 1 else 0.5 - g
        eta = 0.5 + g if (k >> 1) & 1 else 0.5 - g
        # mid-surface tangents, reference (G1, G2) and current (g1, g2), and the jump
        G1x = G1y = G1z = G2x = G2y = G2z = 0.0
        g1x = g1y = g1z = g2x = g2y = g2z = 0.0
        jx = jy = jz = 0.0
        for a in range(4):
            nx, dnx = (xi, 1.0) if a & 1 else (1.0 - xi, -1.0)
            ny, dny = (eta, 1.0) if (a >> 1) & 1 else (1.0 - eta, -1.0)
            shape, dxi, deta = nx * ny, dnx * ny, nx * dny
            Xm = 0.5 * (X[a, 0] + X[a + 4, 0])
            Ym = 0.5 * (X[a, 1] + X[a + 4, 1])
            Zm = 0.5 * (X[a, 2] + X[a + 4, 2])
            xm = Xm + 0.5 * (u[a, 0] + u[a + 4, 0])
            ym = Ym + 0.5 * (u[a, 1] + u[a + 4, 1])
            zm = Zm + 0.5 * (u[a, 2] + u[a + 4, 2])
            G1x += dxi * Xm
            G1y += dxi * Ym
            G1z += dxi * Zm
            G2x += deta * Xm
            G2y += deta * Ym
            G2z += deta * Zm
            g1x += dxi * xm
            g1y += dxi * ym
            g1z += dxi * zm
            g2x += deta * xm
            g2y += deta * ym
            g2z += deta * zm
            jx += shape * (u[a + 4, 0] - u[a, 0])
            jy += shape * (u[a + 4, 1] - u[a, 1])
            jz += shape * (u[a + 4, 2] - u[a, 2])
        # reference area element; the local frame (t1 along g1, n normal, t2 = n x t1)
        rx, ry, rz = G1y * G2z - G1z * G2y, G1z * G2x - G1x * G2z, G1x * G2y - G1y * G2x
        dA = math.sqrt(rx**2 + ry**2 + rz**2)
        n0, n1, n2 = g1y * g2z - g1z * g2y, g1z * g2x - g1x * g2z, g1x * g2y - g1y * g2x
        n_norm = math.sqrt(n0**2 + n1**2 + n2**2)
        g1_norm = math.sqrt(g1x**2 + g1y**2 + g1z**2)
        n0, n1, n2 = n0 / n_norm, n1 / n_norm, n2 / n_norm
        a0, a1, a2 = g1x / g1_norm, g1y / g1_norm, g1z / g1_norm
        b0, b1, b2 = n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0
        d1 = jx * a0 + jy * a1 + jz * a2
        d2 = jx * b0 + jy * b1 + jz * b2
        d3 = jx * n0 + jy * n1 + jz * n2
        damage_old = damage[k]
        c = 0.25 * dA
        share = 1.0
        if damage_old >= 1.0:  # broken: its contact lets go of faces slid or pressed through
            held = 1.0 - history[k, H_RELEASED] if track else 1.0
            share = min(held, pressed_share(math.sqrt(d1 * d1 + d2 * d2), -d3, size))
            if track and share < held:
                # the energy let go, in the consistent form of a secant law (as below)
                last = history[k, H_D3]
                pressed = 0.0  # (an open point holds no contact energy)
                if d3 < 0.0:
                    pressed = last * d3 if last < 0.0 else d3 * d3
                history[k, H_DISSIPATED] += 0.5 * (held - share) * params[P_KN] * pressed * c
                history[k, H_RELEASED] = 1.0 - share
        tau1, tau2, tau3, damage[k], psi = _law(d1, d2, d3, params, damage_old, share)
        if track:
            if damage[k] > damage_old:
                # consistent with the trapezoidal work of the secant law (module docstring)
                released = params[P_KS] * (history[k, H_D1] * d1 + history[k, H_D2] * d2)
                if d3 > 0.0 and history[k, H_D3] > 0.0:
                    released += params[P_KN] * history[k, H_D3] * d3
                history[k, H_DISSIPATED] += 0.5 * (damage[k] - damage_old) * released * c
            history[k, H_D1] = d1
            history[k, H_D2] = d2
            history[k, H_D3] = d3
        Tx = tau1 * a0 + tau2 * b0 + tau3 * n0
        Ty = tau1 * a1 + tau2 * b1 + tau3 * n1
        Tz = tau1 * a2 + tau2 * b2 + tau3 * n2
        # The frame turns with the mid-surface: psi(Q^T jump) changes by -w.(delta x t) for a
        # frame rotation w (local axes), so the force is the energy's gradient only with that
        # term (zero where t is parallel to delta: an open, undamaged interface with K_n = K_s).
        # w = (-b.dn, a.dn, b.da) with dn, da from the mid-surface tangents' change: p1, p2
        # below are the energy's gradient with respect to g1 and g2 through the frame.
        m1 = d2 * tau3 - d3 * tau2
        m2 = d3 * tau1 - d1 * tau3
        m3 = d1 * tau2 - d2 * tau1
        v0, v1, v2 = m1 * b0 - m2 * a0, m1 * b1 - m2 * a1, m1 * b2 - m2 * a2
        sn, sa = c / n_norm, c * m3 / g1_norm
        p1x = sn * (g2y * v2 - g2z * v1) - sa * b0
        p1y = sn * (g2z * v0 - g2x * v2) - sa * b1
        p1z = sn * (g2x * v1 - g2y * v0) - sa * b2
        p2x = sn * (v1 * g1z - v2 * g1y)
        p2y = sn * (v2 * g1x - v0 * g1z)
        p2z = sn * (v0 * g1y - v1 * g1x)
        for a in range(4):
            nx, dnx = (xi, 1.0) if a & 1 else (1.0 - xi, -1.0)
            ny, dny = (eta, 1.0) if (a >> 1) & 1 else (1.0 - eta, -1.0)
            shape, dxi, deta = nx * ny, 0.5 * dnx * ny, 0.5 * nx * dny
            turn_x = dxi * p1x + deta * p2x  # (half: x_mid takes half of each face's motion)
            turn_y = dxi * p1y + deta * p2y
            turn_z = dxi * p1z + deta * p2z
            f_coh[a, 0] += shape * Tx * c - turn_x
            f_coh[a, 1] += shape * Ty * c - turn_y
            f_coh[a, 2] += shape * Tz * c - turn_z
            f_coh[a + 4, 0] -= shape * Tx * c + turn_x
            f_coh[a + 4, 1] -= shape * Ty * c + turn_y
            f_coh[a + 4, 2] -= shape * Tz * c + turn_z
        energy += psi * c
        area += c
    return energy, area


# error_model "numpy": a mid-surface collapsed to a line or a point (no normal) gives NaN
# forces, which the run's not-finite guard reports, rather than an exception from the kernel
@njit(cache=True, error_model="numpy")
def cohesive_element_force(
    X: np.ndarray, u: np.ndarray, params: np.ndarray, damage: np.ndarray, f_coh: np.ndarray
) -> tuple[float, float]:
    """Force of one 8-node cohesive element; see the module docstring for node order and sign.

    X, u: (8, 3) reference coordinates and displacements. damage: (4,) per Gauss point, updated
    in place. f_coh: (8, 3), overwritten. Returns (stored energy in mJ, reference area in mm^2).
    """
    return _element_force(X, u, params, damage, np.empty((4, HISTORY)), False, f_coh)


@njit(cache=True, error_model="numpy")
def cohesive_element_force_tracked(
    X: np.ndarray,
    u: np.ndarray,
    params: np.ndarray,
    damage: np.ndarray,
    history: np.ndarray,
    f_coh: np.ndarray,
) -> tuple[float, float]:
    """``cohesive_element_force``, also accumulating the energy the damage of each point
    dissipates: ``history`` (4, HISTORY) per Gauss point, updated in place: H_D1, H_D2, H_D3
    the local opening (mm) of the last call, H_DISSIPATED the energy (mJ) dissipated so far."""
    return _element_force(X, u, params, damage, history, True, f_coh)


@njit(cache=True, error_model="numpy")
def cohesive_tangents(X, u, params, damage, step, K):
    """Tangent stiffnesses (N/mm) of cohesive elements' share of the internal force, -f_coh,
    into ``K`` (n, 24, 24) (DOF 3 node + component): central differences of the law about the
    displacements ``u`` (n, 8, 3) mm with the probe ``step`` (mm), each probe from the damage
    ``damage`` (n, 4) as it is (left unchanged). Reference positions ``X`` (n, 8, 3) mm."""
    trial = np.empty((8, 3))
    plus = np.empty((8, 3))
    minus = np.empty((8, 3))
    points = np.empty(4)
    unused = np.zeros((4, HISTORY))
    for e in range(X.shape[0]):
        for j in range(24):
            a, c = j // 3, j % 3
            for sign in (1.0, -1.0):
                trial[:, :] = u[e]
                trial[a, c] += sign * step
                points[:] = damage[e]
                out = plus if sign > 0 else minus
                _element_force(X[e], trial, params, points, unused, False, out)
            for i in range(24):
                K[e, i, j] = -(plus[i // 3, i % 3] - minus[i // 3, i % 3]) / (2.0 * step)


def traction_separation_curve(
    law: CohesiveLaw, path: np.ndarray, damage: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the law along ``path`` (n, 3) of local openings from the initial ``damage``; returns
    tractions (n, 3), damage (n,) and stored energy density (n,) after each point."""
    path = np.asarray(path, dtype=np.float64).reshape(-1, 3)
    params = law.as_array()
    tractions = np.empty_like(path)
    damages = np.empty(len(path))
    stored = np.empty(len(path))
    for j, delta in enumerate(path):
        tractions[j], damage, stored[j] = cohesive_traction(delta, params, damage)
        damages[j] = damage
    return tractions, damages, stored
