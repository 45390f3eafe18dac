"""Ply materials and laminates.

Units: N, mm, s, tonne (stiffness in MPa, density in tonne/mm^3).

Frames. The shell frame is global: x along the beam/plate, y across, z the laminate normal (the
meshes in ``meshes/`` are flat and extruded along z). A ply's material frame has axis 1 along the
fibres, 2 in-plane transverse, 3 = z; the ply angle (degrees) turns axis 1 about z, from x
towards y. Voigt order everywhere is (xx, yy, zz, yz, xz, xy) with engineering shear strains.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fenics_adaptive.errors import InputError

# Voigt index -> tensor index pair, in the order (xx, yy, zz, yz, xz, xy).
VOIGT_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


@dataclass(frozen=True)
class PlyMaterial:
    """Transversely isotropic elastic ply (isotropic in the 2-3 plane): E3 = E2, G13 = G12,
    nu13 = nu12. ``G23`` may be given; if omitted it is E2 / (2 (1 + nu23)), the value transverse
    isotropy implies."""

    name: str
    E1: float
    E2: float
    G12: float
    nu12: float
    nu23: float
    rho: float
    G23: float | None = None

    REQUIRED = ("E1", "E2", "G12", "nu12", "nu23", "rho")
    OPTIONAL = ("G23",)

    def __post_init__(self) -> None:
        key = f"materials.{self.name}"
        for field in ("E1", "E2", "G12", "rho") + (("G23",) if self.G23 is not None else ()):
            value = getattr(self, field)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise InputError(f"{key}.{field}", f"must be a number > 0 (got {value!r})")
        for field in ("nu12", "nu23"):
            value = getattr(self, field)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise InputError(f"{key}.{field}", f"must be a number (got {value!r})")
        if not -1.0 < self.nu23 < 1.0:
            raise InputError(f"{key}.nu23", f"must lie in (-1, 1) (got {self.nu23})")
        eigenvalues = np.linalg.eigvalsh(self.compliance())
        if eigenvalues.min() <= 0.0:
            raise InputError(
                f"{key}.nu12",
                f"the stiffness is not positive definite with nu12={self.nu12}, "
                f"nu23={self.nu23}, E1={self.E1}, E2={self.E2} (need nu12^2 < E1/E2 * (1-nu23)/2)",
            )

    @classmethod
    def from_mapping(cls, name: str, values: Mapping[str, object]) -> PlyMaterial:
        key = f"materials.{name}"
        if not isinstance(values, Mapping):
            raise InputError(key, "must be a table of ply properties")
        unknown = sorted(set(values) - set(cls.REQUIRED) - set(cls.OPTIONAL))
        if unknown:
            raise InputError(
                f"{key}.{unknown[0]}",
                f"unknown key (allowed: {', '.join(cls.REQUIRED + cls.OPTIONAL)})",
            )
        for field in cls.REQUIRED:
            if field not in values:
                raise InputError(f"{key}.{field}", "missing")
        for field, value in values.items():
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InputError(f"{key}.{field}", f"must be a number (got {value!r})")
        return cls(name=name, **{k: float(v) for k, v in values.items()})

    @property
    def shear_modulus_23(self) -> float:
        return self.G23 if self.G23 is not None else self.E2 / (2.0 * (1.0 + self.nu23))

    def compliance(self) -> np.ndarray:
        """6x6 compliance in the material frame (Voigt, engineering shear)."""
        E1, E2, nu12, nu23 = self.E1, self.E2, self.nu12, self.nu23
        S = np.zeros((6, 6))
        S[0, 0] = 1.0 / E1
        S[1, 1] = S[2, 2] = 1.0 / E2
        S[0, 1] = S[1, 0] = S[0, 2] = S[2, 0] = -nu12 / E1
        S[1, 2] = S[2, 1] = -nu23 / E2
        S[3, 3] = 1.0 / self.shear_modulus_23
        S[4, 4] = S[5, 5] = 1.0 / self.G12
        return S

    def stiffness(self) -> np.ndarray:
        """6x6 stiffness in the material frame."""
        return np.linalg.inv(self.compliance())

    def dilatational_wave_speed(self) -> float:
        """Fastest plane dilatational wave, sqrt(max(C11, C22, C33) / rho), in mm/s."""
        C = self.stiffness()
        return math.sqrt(max(C[0, 0], C[1, 1], C[2, 2]) / self.rho)


def voigt_to_tensor(C: np.ndarray) -> np.ndarray:
    """Stiffness 6x6 (engineering shear strains) -> 3x3x3x3 tensor."""
    T = np.zeros((3, 3, 3, 3))
    for a, (i, j) in enumerate(VOIGT_PAIRS):
        for b, (k, l) in enumerate(VOIGT_PAIRS):
            T[i, j, k, l] = T[j, i, k, l] = T[i, j, l, k] = T[j, i, l, k] = C[a, b]
    return T


def tensor_to_voigt(T: np.ndarray) -> np.ndarray:
    return np.array([[T[i, j, k, l] for (k, l) in VOIGT_PAIRS] for (i, j) in VOIGT_PAIRS])


def rotation_about_z(angle_deg: float) -> np.ndarray:
    """Columns are the material axes 1, 2, 3 in shell (global) coordinates."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotate_stiffness(C_material: np.ndarray, angle_deg: float) -> np.ndarray:
    """Material-frame 6x6 stiffness -> shell-frame 6x6 stiffness for a ply at ``angle_deg``."""
    R = rotation_about_z(angle_deg)
    T = np.einsum("ia,jb,kc,ld,abcd->ijkl", R, R, R, R, voigt_to_tensor(C_material))
    C = tensor_to_voigt(T)
    # cos(90 deg) is 6e-17, not 0: drop such round-off so that a 90-degree ply's stiffness has the
    # exact zeros (no shear coupling) that the element's integration rule relies on.
    C[np.abs(C) < 1e-14 * np.abs(C).max()] = 0.0
    return C


@dataclass(frozen=True)
class Ply:
    material: PlyMaterial
    angle: float  # degrees, fibre direction from x towards y about z
    thickness: float  # mm

    def stiffness(self) -> np.ndarray:
        """6x6 stiffness in the shell frame (a new array)."""
        return _shell_frame_stiffness(self.material, self.angle).copy()


@functools.lru_cache(maxsize=1024)
def _shell_frame_stiffness(material: PlyMaterial, angle: float) -> np.ndarray:
    # the indicators ask for every ply's at each evaluation: formed once per material and angle
    return rotate_stiffness(material.stiffness(), angle)


@dataclass(frozen=True)
class Laminate:
    """Plies listed from the bottom (z = z_min) to the top. Interface i (1-based) lies between
    ply i and ply i + 1, at the thickness fraction ``interface_fractions[i - 1]``."""

    plies: tuple[Ply, ...]

    def __post_init__(self) -> None:
        if len(self.plies) == 0:
            raise InputError("laminate.plies", "a laminate needs at least one ply")
        for k, ply in enumerate(self.plies):
            key = f"laminate.plies[{k}]"
            if not (math.isfinite(ply.thickness) and ply.thickness > 0):
                raise InputError(f"{key}.thickness", f"must be > 0 mm (got {ply.thickness})")
            if not (math.isfinite(ply.angle) and -360.0 <= ply.angle <= 360.0):
                raise InputError(
                    f"{key}.angle", f"must be in degrees within [-360, 360] (got {ply.angle})"
                )

    @classmethod
    def from_angles(
        cls, material: PlyMaterial, angles: Sequence[float], ply_thickness: float
    ) -> Laminate:
        return cls(tuple(Ply(material, float(a), float(ply_thickness)) for a in angles))

    @property
    def n_plies(self) -> int:
        return len(self.plies)

    @property
    def thickness(self) -> float:
        return sum(p.thickness for p in self.plies)

    @property
    def ply_fractions(self) -> np.ndarray:
        """Thickness fractions of the ply boundaries, bottom to top: 0 = f_0 < ... < f_n = 1."""
        z = np.concatenate([[0.0], np.cumsum([p.thickness for p in self.plies])])
        return z / z[-1]

    @property
    def interface_fractions(self) -> np.ndarray:
        """alpha_i of the paper's Eq. (1) for the n - 1 ply interfaces."""
        return self.ply_fractions[1:-1]

    def ply_stiffnesses(self) -> list[np.ndarray]:
        return [p.stiffness() for p in self.plies]

    def areal_mass(self) -> float:
        """Mass per unit mid-surface area, tonne/mm^2."""
        return sum(p.material.rho * p.thickness for p in self.plies)

    def abd(self) -> np.ndarray:
        """Classical laminate theory 6x6 [[A, B], [B, D]] (plane stress in each ply), in N/mm,
        N, N mm; z measured from the laminate mid-plane."""
        z = self.ply_fractions * self.thickness - 0.5 * self.thickness
        A = np.zeros((3, 3))
        B = np.zeros((3, 3))
        D = np.zeros((3, 3))
        for k, ply in enumerate(self.plies):
            Q = reduced_plane_stress_stiffness(ply.stiffness())
            A += Q * (z[k + 1] - z[k])
            B += Q * (z[k + 1] ** 2 - z[k] ** 2) / 2.0
            D += Q * (z[k + 1] ** 3 - z[k] ** 3) / 3.0
        return np.block([[A, B], [B, D]])

    def narrow_beam_bending_stiffness(self, width: float) -> float:
        """EI (N mm^2) of a narrow beam along x with free sides: b / d11, where d = inv(ABD)
        restricted to the bending curvature kappa_x (N = 0, M_y = M_xy = 0)."""
        d = np.linalg.inv(self.abd())
        return width / d[3, 3]


def reduced_plane_stress_stiffness(C: np.ndarray) -> np.ndarray:
    """3x3 in-plane (xx, yy, xy) stiffness with sigma_zz = sigma_yz = sigma_xz = 0."""
    S = np.linalg.inv(C)
    in_plane = [0, 1, 5]
    return np.linalg.inv(S[np.ix_(in_plane, in_plane)])


def bending_about_neutral_plane(laminate: Laminate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a laminate bends with, in x and in y: the ply boundaries z (n + 1,) mm from the
    bottom face, and for the two directions each ply's reduced plane-stress modulus E (2, n)
    MPa (Qbar_11, Qbar_22), the neutral plane z_n (2,) mm and the exact bending stiffness
    D = int E (z - z_n)^2 dz (2,) N mm (per unit width)."""
    z = laminate.ply_fractions * laminate.thickness
    Q = np.array([reduced_plane_stress_stiffness(ply.stiffness()) for ply in laminate.plies])
    E = np.stack([Q[:, 0, 0], Q[:, 1, 1]])
    z_n = np.sum(E * (z[1:] ** 2 - z[:-1] ** 2) / 2, axis=1) / np.sum(E * np.diff(z), axis=1)
    lower, upper = z[:-1] - z_n[:, None], z[1:] - z_n[:, None]
    D = np.sum(E * (upper**3 - lower**3) / 3, axis=1)
    return z, E, np.stack([z_n, D])


def element_shear_factors(
    laminate: Laminate, first: int, stop: int, shear_correction: bool = True
) -> tuple[float, float]:
    """(k_xz, k_yz) that a (sub)element spanning plies [first, stop) of ``laminate`` carries:
    ``shear_correction_factors`` for a span of several plies, (1, 1) for a single ply or
    without ``shear_correction``.

    The element's shear stiffness; its plies share it as ``ply_shear_factors`` says, the one
    rule for the UFL forms (``model.forms.LayeredModel``) and the numba rules
    (``element.rules.RuleTable``). A one-ply element is a 3D solid layer: the layerwise
    reference keeps the plies' own shear moduli (a constant transverse shear passes the patch
    test exactly), and refined-from-start stays equal to it."""
    if not shear_correction or stop - first == 1:
        _check_span(laminate, first, stop)
        return 1.0, 1.0
    return shear_correction_factors(laminate, first, stop)


def _check_span(laminate: Laminate, first: int, stop: int) -> None:
    """Refuse (ValueError) a span [first, stop) that is not one of ``laminate``'s plies."""
    if not 0 <= first < stop <= laminate.n_plies:
        raise ValueError(f"no ply span [{first}, {stop}) in a laminate of {laminate.n_plies} plies")


def shear_correction_factors(
    laminate: Laminate, first: int = 0, stop: int | None = None
) -> tuple[float, float]:
    """Transverse shear correction factors (k_xz, k_yz) of an element spanning plies
    [first, stop) of ``laminate`` (default: all of them), for an element whose transverse shear
    strain is constant through its thickness, as a solid-shell's is.

    The exact distribution of the transverse shear stress in a laminate bent by a shear force
    Q follows from equilibrium with the plies' bending stresses (Whitney, J. Compos. Mater. 7,
    1973; the "laminated shell theory" of LS-DYNA's shells): tau_xz(z) = Q g(z) with
    g(z) = 1/D int_{z_bottom}^{z} E(s) (z_n - s) ds, where E is each ply's reduced plane-stress
    modulus Qbar_11 (Qbar_22 for yz), z_n the laminate's neutral plane and D its bending
    stiffness, so that int g dz = 1 over the laminate. On the span [a, b] the element carries
    the share Q_s = Q int_a^b g dz with a constant strain; its complementary energy equals the
    exact one, 1/2 Q^2 int_a^b g^2 / G dz, when its shear moduli G(z) (C_55, C_44 in the shell
    frame) are scaled by

        k = (int_a^b g dz)^2 / (int_a^b G dz * int_a^b g^2 / G dz)   (<= 1, Cauchy-Schwarz).

    A homogeneous section gives 5/6; a thin span inside the laminate, where g hardly varies,
    tends to 1, so a refined model converges to the layerwise one as its sublaminates thin.
    The distribution is the laminate's as a whole: that of the intact laminate, which a
    sublaminate of a delaminated cell only approximates.

    Returns:
        (k_xz, k_yz), each in (0, 1].
    """
    k = _correction(*_span_shear_distribution(laminate, first, stop))
    return float(k[0]), float(k[1])


def _correction(share, energy, G, h) -> np.ndarray:
    """(2,) k_xz, k_yz of a span from its plies' ``_span_shear_distribution``:
    (int g)^2 / (int G * int g^2 / G)."""
    return share.sum(axis=1) ** 2 / ((G * h).sum(axis=1) * energy.sum(axis=1))


def _span_shear_distribution(
    laminate: Laminate, first: int, stop: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Of the plies [first, stop) of ``laminate``, per direction (xz, yz) and ply: int g dz
    and int g^2 / G dz over the ply (mm, mm / MPa; g of ``shear_correction_factors``), the
    shear modulus G (MPa) and the thickness (mm): four (2, stop - first) arrays."""
    stop = laminate.n_plies if stop is None else stop
    _check_span(laminate, first, stop)
    z, moduli, (neutral, bending) = bending_about_neutral_plane(laminate)
    h = np.diff(z)
    stiffness = [ply.stiffness() for ply in laminate.plies]
    # 3 Gauss points per ply integrate g^2 (a quartic within a ply) exactly
    x, w = np.polynomial.legendre.leggauss(3)
    n = stop - first
    share, energy, moduli_out = np.zeros((2, n)), np.zeros((2, n)), np.zeros((2, n))
    directions = zip(moduli, neutral, bending, (4, 3), strict=True)
    for d, (modulus, z_n, D, shear) in enumerate(directions):
        G = np.array([C[shear, shear] for C in stiffness])

        def primitive(k: int, s: np.ndarray, E=modulus, z_n=z_n) -> np.ndarray:
            """int_{z_k}^{s} E_k (z_n - t) dt within ply k."""
            return E[k] * (z_n * (s - z[k]) - (s**2 - z[k] ** 2) / 2)

        g_bottom = (
            np.concatenate([[0.0], np.cumsum([primitive(k, z[k + 1]) for k in range(len(h))])]) / D
        )
        for j, k in enumerate(range(first, stop)):
            s = z[k] + 0.5 * h[k] * (x + 1)
            g = g_bottom[k] + primitive(k, s) / D
            share[d, j] = 0.5 * h[k] * np.sum(w * g)
            energy[d, j] = 0.5 * h[k] * np.sum(w * g**2) / G[k]
        moduli_out[d] = G[first:stop]
    return share, energy, moduli_out, np.broadcast_to(h[first:stop], (2, n)).copy()


def ply_shear_factors(
    laminate: Laminate, first: int, stop: int, shear_correction: bool = True
) -> np.ndarray:
    """(stop - first, 2): the factors m_k (xz, yz) on the transverse shear stiffness of each
    ply k of a (sub)element spanning plies [first, stop) of ``laminate``, so that its plies'
    shear stresses follow the laminate's distribution (the laminated shell theory of
    ``shear_correction_factors``) while the element keeps the shear stiffness that
    ``element_shear_factors`` gives it.

    The element's transverse shear strain gamma is constant through its thickness; ply k's
    is sqrt(m_k) gamma (its energy 1/2 G_k m_k gamma^2), m_k = c (g_k / G_k)^2, g_k the ply's
    mean of the laminate's shear distribution g (``shear_correction_factors``), so that each
    ply's stress G_k sqrt(m_k) gamma is proportional to g_k: smallest in the outer plies of a
    bent laminate, largest near its neutral plane (with k G_k, every ply would carry the same
    stress times its modulus: an
    outer 90-degree ply of a cross-ply beam in the shear span would see the mean shear stress
    of the section, and crack in shear where the layerwise model's does not). c is set by
    sum_k t_k G_k m_k = k sum_k t_k G_k: the element's shear stiffness is unchanged. A single
    ply, or no ``shear_correction``: 1.
    """
    if not shear_correction or stop - first == 1:
        _check_span(laminate, first, stop)
        return np.ones((stop - first, 2))
    share, energy, G, h = _span_shear_distribution(laminate, first, stop)
    k = _correction(share, energy, G, h)
    mean = share / h
    shape = (mean / G) ** 2
    c = k * (G * h).sum(axis=1) / (G * h * shape).sum(axis=1)
    return (c[:, None] * shape).T
