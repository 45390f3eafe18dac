"""Adaptivity settings as the config gives them: which ply interfaces may refine, the
stabilisation of a refinement, the refinement indicators, the manual refinements and the
initial delaminations (standard library only; ``model.structure`` and
``adaptivity.indicators`` act on them).

Units: N, mm, s, tonne. Ply interfaces are 1-based: interface i lies between ply i and ply i + 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fenics_adaptive.settings.kinds import InterfaceState, Refinement
from fenics_adaptive.settings.loads import Region


@dataclass(frozen=True)
class Interfaces:
    """Ply interfaces (1-based: interface i lies between ply i and ply i + 1) that may refine
    weakly (``refine``), may delaminate (``delaminate``: strong refinement in an adaptive model,
    cohesive elements in a layerwise one), and carry the symmetry condition (``symmetry``: their
    nodes held on their reference plane, u_z = 0). ``initial``: state of the listed interfaces
    of an adaptive model at t = 0 ("none", "weak", "strong": refined from the start)."""

    refine: tuple[int, ...] = ()
    delaminate: tuple[int, ...] = ()
    symmetry: tuple[int, ...] = ()
    initial: Refinement = Refinement.NONE

    def __post_init__(self) -> None:
        object.__setattr__(self, "initial", Refinement(self.initial))  # frozen: set once, here


@dataclass(frozen=True)
class Delamination:
    """An insert film: interface ``interface`` (1-based) delaminated at t = 0 over the cells
    whose centroid lies in ``region``. A layerwise model starts with
    these cohesive elements failed; an adaptive one with these cells refined strongly at the
    interface and their cohesive elements failed. The crack faces still meet: the cohesive law's
    compression branch is never damaged (frictionless contact through the normal penalty)."""

    interface: int
    region: Region


@dataclass(frozen=True)
class Stabilisation:
    """The paper's remedies for the sudden change of internal forces on refinement (user
    parameters). After a weak refinement the nodes of the refined cells get mass-proportional
    damping ``damping`` (1/s) for ``damping_window`` (s). After a strong refinement a tie force
    holds each new node pair together: at the moment of refinement it makes the two nodes
    accelerate together exactly as the continuous interface did (it cancels the jump in
    internal force that splitting causes; Menouillard & Belytschko 2010), and it is released
    linearly to zero over ``release_window`` (s); 0 inserts the crack abruptly. A tie also lets
    go of a pair that moves on (``adaptivity.stabilisation.TieRelease``): opened against it past
    its reach, the opening at which the pair's cohesive element carries the tie's force
    (released by the law's final opening), or moved the way it pushes (then it pushes with at
    most what the element carries at its onset and lets go before it), so that it never pushes
    an interface open. Before either acts, ``equilibrate`` puts the nodes of the refined cells
    in balance (``equilibrates``, ``adaptivity.equilibration``)."""

    damping: float = 0.0
    damping_window: float = 0.0
    release_window: float = 0.0
    # the refined cells' nodes start in balance, each with the acceleration it had
    # (``adaptivity.equilibration``); False: where the split element's field puts them; None
    # (the default): on for a model without ply damage, off with it (``equilibrates``)
    equilibrate: bool | None = None

    def equilibrates(self, ply_damage: bool) -> bool:
        """Whether refinements put the refined cells' nodes in balance, for a model with or
        without ``ply_damage``. Left to the default, not with ply damage: the balance is found
        with the undamaged plies' tangent, which a damaged ply's is not, and the evidence is
        split (README, Indicators and stabilisation): on the crash demo (a plate broken by a
        sphere, ply damage, erosion, finite strain) the balanced run absorbed 0.64 x the
        layerwise energy where the placed one absorbs 0.999 x, while the four-point bending
        beam came within 3 % of layerwise balanced (10-12 % more dissipation placed)."""
        return (not ply_damage) if self.equilibrate is None else self.equilibrate

    @property
    def damps(self) -> bool:
        return self.damping > 0.0 and self.damping_window > 0.0


# [indicators] interface_stress where an interface may delaminate and the config is silent:
# strong refinement once the estimated interlaminar stress reaches 90 % of the cohesive
# initiation criterion, so that the cohesive elements are in place before their traction
# reaches the strength (between two evaluations the stress may rise further; a cell refined
# above its strength would open at once)
DEFAULT_INTERFACE_STRESS = 0.9


@dataclass(frozen=True)
class IndicatorSettings:
    """Which indicators run, every ``interval`` seconds (None, the default: the time a shear
    wave takes to cross the band refined ahead of a front, ``indicators.default_interval``):
    fractions of 1 for the ply failure
    index (weak) and the interface initiation criterion (strong), matrix damage (strong), how
    many rings of neighbours refine with a flagged cell, and ``strong_after``: a delaminable
    interface refined weakly turns strong that long after (the paper's four-point bending:
    damping for 0.2 ms after the weak refinement, then the strong one). ``front_distance``
    (mm): the delamination front stays inside the refined region: the cells whose centroid
    lies within that distance of the centroid of a cell whose cohesive element has started to
    fail refine strongly at that interface, so that the border constraint of the refined
    region never holds the process zone or the stress peak ahead of it. None (the default):
    each interface's own, the process zone length plus two sublaminate thicknesses
    (``indicators.front_distances``); 0: none. ``look_ahead``: ``interface_stress`` compares
    its threshold with the index predicted at the end of the time a refinement takes to act
    (the interval plus the stabilisation's release window) as well, the rise of the last such
    time continued (``indicators.IndexHistory``)."""

    interval: float | None = None  # s
    ply_failure: float | None = None
    interface_stress: float | None = None
    matrix_damage: bool = False
    spread: int = 0
    strong_after: float | None = None  # s: a weak delaminable interface turns strong this late
    front_distance: float | None = None  # mm, around cohesive elements that have started to fail
    # interface_stress also on the index predicted one lead time ahead (``IndexHistory``)
    look_ahead: bool = True


@dataclass(frozen=True)
class Manual:
    """Refine ``interfaces`` (``kind``) of the cells with centroid in [x_min, x_max] once the
    time reaches ``time`` or the probe displacement (absolute value) reaches
    ``displacement``."""

    interfaces: tuple[int, ...]
    kind: InterfaceState  # WEAK or STRONG
    time: float = math.inf
    displacement: float = math.inf
    x_min: float = -math.inf
    x_max: float = math.inf

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", InterfaceState(self.kind))  # frozen: set once, here

    def due(self, t: float, displacement: float) -> bool:
        """Whether the refinement is due at time ``t`` (s) and probe ``displacement`` (mm)."""
        return t >= self.time or abs(displacement) >= self.displacement
