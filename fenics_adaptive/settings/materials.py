"""Material data as the config gives it: the failure data of a ply material and the cohesive law
of the interfaces (standard library and numpy only: no kernels here).

Units: N, mm, s, tonne. Strengths in MPa, fracture energies in N/mm (= mJ/mm^2), penalty
stiffnesses in N/mm^3. The formulas that use these data are in ``materials.ply_damage`` and
``materials.cohesive``; the slot constants below are the layout of the parameter arrays those
kernels read (``as_array``), defined here beside the one method that fills them.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from fenics_adaptive.errors import InputError
from fenics_adaptive.settings.kinds import MixedModeLaw

# ----------------------------------------------------------------- ply failure (ply_damage)
# Slots of PlyFailure.as_array() (the first N_FAILURE slots of a ply's parameter row).
# F_GFT = F_GFC = 0: no fibre damage (fibre failure an index only).
F_XT, F_XC, F_YT, F_YC, F_S12, F_S23, F_G2C, F_G6C, F_GFT, F_GFC = range(10)
N_FAILURE = 10
# Puck's fracture angle under pure transverse compression; S23 defaults to YC / (2 tan 53 deg)
# (Puck & Schuermann; LaRC04, Pinho et al.).
FRACTURE_ANGLE_DEG = 53.0


@dataclass(frozen=True)
class PlyFailure:
    """Strengths (MPa) and fracture energies (N/mm) of one ply material.

    XT, XC: fibre tension / compression strength; YT, YC: transverse tension / compression;
    S12: in-plane shear; S23: transverse shear (optional, default YC / (2 tan 53 deg));
    G2c: matrix mode I (transverse tension) fracture energy; G6c: matrix in-plane shear
    fracture energy; Gft, Gfc: fibre tension / fibre (kink-band) compression fracture energy
    (optional, both or neither: without them fibre failure is an index only, with them the
    fibres break, ``materials.ply_damage``). All > 0, and S23 > YT / 2 (else Hashin's matrix
    tension criterion never reaches 1 under equal biaxial transverse tension)."""

    name: str
    XT: float
    XC: float
    YT: float
    YC: float
    S12: float
    G2c: float
    G6c: float
    S23: float | None = None
    Gft: float | None = None
    Gfc: float | None = None

    REQUIRED = ("XT", "XC", "YT", "YC", "S12", "G2c", "G6c")
    OPTIONAL = ("S23", "Gft", "Gfc")

    def __post_init__(self) -> None:
        key = f"materials.{self.name}.failure"
        if (self.Gft is None) != (self.Gfc is None):
            missing = "Gfc" if self.Gfc is None else "Gft"
            raise InputError(
                f"{key}.{missing}",
                "missing: fibre damage needs both fibre fracture energies, Gft (tension) and "
                "Gfc (compression); give neither to keep fibre failure an index",
            )
        given = tuple(f for f in self.OPTIONAL if getattr(self, f) is not None)
        for field in self.REQUIRED + given:
            value = getattr(self, field)
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not math.isfinite(value)
                or value <= 0
            ):
                raise InputError(f"{key}.{field}", f"must be a finite number > 0 (got {value!r})")
        S23 = self.transverse_shear_strength
        if not S23 > 0.5 * self.YT:
            given = "" if self.S23 is not None else f" (default YC / (2 tan 53 deg) = {S23:.6g})"
            raise InputError(
                f"{key}.S23",
                f"the transverse shear strength {S23:.6g}{given} must exceed YT/2 = "
                f"{0.5 * self.YT:.6g} (Hashin's matrix tension criterion would never be "
                "reached under equal biaxial transverse tension); give S23 explicitly",
            )

    @classmethod
    def from_mapping(cls, name: str, values: Mapping[str, object]) -> PlyFailure:
        """Build from the config table ``materials.NAME.failure``: exactly the keys XT, XC, YT,
        YC, S12, G2c, G6c and optionally S23, and Gft with Gfc."""
        key = f"materials.{name}.failure"
        if not isinstance(values, Mapping):
            raise InputError(key, "must be a table of strengths and fracture energies")
        allowed = cls.REQUIRED + cls.OPTIONAL
        unknown = sorted(set(values) - set(allowed))
        if unknown:
            raise InputError(f"{key}.{unknown[0]}", f"unknown key (allowed: {', '.join(allowed)})")
        for field in cls.REQUIRED:
            if field not in values:
                raise InputError(f"{key}.{field}", "missing")
        for field, value in values.items():
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise InputError(f"{key}.{field}", f"must be a number (got {value!r})")
        return cls(name=name, **{k: float(v) for k, v in values.items()})

    @property
    def transverse_shear_strength(self) -> float:
        if self.S23 is not None:
            return self.S23
        return self.YC / (2.0 * math.tan(math.radians(FRACTURE_ANGLE_DEG)))

    @property
    def fibre_damage(self) -> bool:
        """Whether the fibres break (the fibre fracture energies are given)."""
        return self.Gft is not None

    def as_array(self) -> np.ndarray:
        """float64 array for the kernels, slots F_XT, F_XC, F_YT, F_YC, F_S12, F_S23, F_G2C,
        F_G6C, F_GFT, F_GFC (S23 with its default applied; the fibre energies 0 if not
        given)."""
        params = np.empty(N_FAILURE, dtype=np.float64)
        params[F_XT], params[F_XC] = self.XT, self.XC
        params[F_YT], params[F_YC] = self.YT, self.YC
        params[F_S12], params[F_S23] = self.S12, self.transverse_shear_strength
        params[F_G2C], params[F_G6C] = self.G2c, self.G6c
        params[F_GFT], params[F_GFC] = (self.Gft, self.Gfc) if self.fibre_damage else (0.0, 0.0)
        return params


# --------------------------------------------------------------- cohesive law (cohesive)
# Slots of the parameter array given to the numba kernels (see CohesiveLaw.as_array).
P_KN, P_KS, P_N, P_S, P_GIC, P_GIIC, P_LAW, P_EXPONENT = range(8)
N_PARAMS = 8
# Codes of the law in slot P_LAW.
LAW_BK = 0.0
LAW_POWER = 1.0
LAW_CODES = {MixedModeLaw.BK: LAW_BK, MixedModeLaw.POWER: LAW_POWER}


@dataclass(frozen=True)
class CohesiveLaw:
    """Parameters of the bilinear mixed-mode law; see ``materials.cohesive`` for the formulas.

    ``exponent`` is eta for ``law="bk"`` (Benzeggagh-Kenane) and alpha for ``law="power"``."""

    K_n: float
    K_s: float
    N: float
    S: float
    GIc: float
    GIIc: float
    law: MixedModeLaw  # a plain "bk" / "power" is taken and stored as the member
    exponent: float

    NUMBERS = ("K_n", "K_s", "N", "S", "GIc", "GIIc", "exponent")

    def __post_init__(self) -> None:
        for name in self.NUMBERS:
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not math.isfinite(value)
                or value <= 0
            ):
                raise InputError(f"cohesive.{name}", f"must be a finite number > 0 (got {value!r})")
        if self.law not in LAW_CODES:
            raise InputError(
                "cohesive.law", f"must be one of {', '.join(MixedModeLaw)} (got {self.law!r})"
            )
        object.__setattr__(self, "law", MixedModeLaw(self.law))  # frozen: set once, here
        for mode, G, strength, K, G_name, S_name, K_name in (
            ("I", self.GIc, self.N, self.K_n, "GIc", "N", "K_n"),
            ("II", self.GIIc, self.S, self.K_s, "GIIc", "S", "K_s"),
        ):
            onset_energy = strength**2 / (2.0 * K)
            if G <= onset_energy:
                raise InputError(
                    f"cohesive.{G_name}",
                    f"softening impossible in pure mode {mode}: {G_name} = {G} must exceed the "
                    f"elastic energy at onset {S_name}^2/(2 {K_name}) = {onset_energy:.6g}, "
                    f"else the final opening {2.0 * G / strength:.6g} mm is not beyond the onset "
                    f"opening {strength / K:.6g} mm",
                )

    @classmethod
    def from_mapping(cls, values: Mapping[str, object]) -> CohesiveLaw:
        """Build from a config table with exactly the keys K_n, K_s, N, S, GIc, GIIc, law,
        exponent."""
        if not isinstance(values, Mapping):
            raise InputError("cohesive", "must be a table of cohesive-law parameters")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise InputError(f"cohesive.{unknown[0]}", f"unknown key (allowed: {', '.join(names)})")
        for name in names:
            if name not in values:
                raise InputError(f"cohesive.{name}", "missing")
        return cls(**{name: values[name] for name in names})

    def as_array(self) -> np.ndarray:
        """The parameters as a float64 array for the kernels, slots P_KN ... P_EXPONENT."""
        params = np.empty(N_PARAMS, dtype=np.float64)
        params[P_KN], params[P_KS] = self.K_n, self.K_s
        params[P_N], params[P_S] = self.N, self.S
        params[P_GIC], params[P_GIIC] = self.GIc, self.GIIc
        params[P_LAW] = LAW_CODES[self.law]
        params[P_EXPONENT] = self.exponent
        return params
