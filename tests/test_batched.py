"""The batched (lane-vectorised) subelement kernel against the one-element reference kernel.

Units: N, mm, s, tonne.

``batched.add_subelement_forces`` is every elastic solid element's production path; ``subelement``'s
``solid_shell_force`` computes one element with the same mathematics in another loop order. Here
both compute the same elements (distorted, off-axis plies, enhanced thickness strain, several
rules interleaved, more elements than one batch holds, nodes among base and extra arrays, some
elements sharing nodes) and must agree to round-off, small strain and finite.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import distorted_hex, laminate_rule, random_laminate

from fenics_adaptive.element import batched
from fenics_adaptive.element import subelement as se
from fenics_adaptive.model.assembly import SubelementSet, add_subelement_forces


def _rules(rng: np.random.Generator) -> list[se.PackedRule]:
    laminate = random_laminate(rng, 6)
    C = np.array(laminate.ply_stiffnesses())
    f = laminate.ply_fractions
    return [
        laminate_rule(laminate, 1),  # an ESL element
        se.pack_rule(se.sublaminate_ply_zeta(f, 0, 2), C[0:2], 2, enhanced=True),
        se.pack_rule(se.sublaminate_ply_zeta(f, 2, 3), C[2:3], 3, (0.9, 0.8), enhanced=True),
        se.pack_rule(se.sublaminate_ply_zeta(f, 3, 6), C[3:], 2, preintegrate=True, enhanced=True),
    ]


def _elements(rng: np.random.Generator, n_rules: int, ne: int):
    """``ne`` elements of random rules, each on its own 8 nodes except a few that repeat an
    earlier element's nodes (their forces add on the same nodes); nodes shuffled among a base
    and an extra array."""
    rule_of_element = rng.integers(0, n_rules, ne).astype(np.int64)
    own = rng.permutation(8 * ne).reshape(ne, 8)
    for e in rng.choice(np.arange(1, ne), ne // 5, replace=False):
        own[e] = own[rng.integers(0, e)]
    X = np.zeros((8 * ne, 3))
    for nodes in own[::-1]:  # the first owner's coordinates win
        X[nodes] = distorted_hex(rng)
    n_base = 3 * ne
    return rule_of_element, own.astype(np.int32), X, n_base


@pytest.mark.parametrize("finite", [False, True])
@pytest.mark.parametrize("ne", [1, 7, 53])
def test_batched_kernel_equals_one_element_kernel(finite, ne):
    rng = np.random.default_rng(ne + 100 * finite)
    rules = _rules(rng)
    packed = se.concatenate_rules(rules)
    rule_of_element, nodes, X, n_base = _elements(rng, len(rules), ne)
    U = rng.normal(scale=2e-2 if finite else 1e-3, size=X.shape)
    if finite:  # a large rigid rotation on top, which the finite kernel must not see as strain
        c, s = np.cos(1.1), np.sin(1.1)
        U += X @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T - X
    f_ref = np.zeros_like(X)
    energy_ref = 0.0
    for e in range(ne):
        f_e = np.empty((8, 3))
        energy_ref += se.solid_shell_force(
            X[nodes[e]], U[nodes[e]], *rules[rule_of_element[e]], f_e, finite
        )
        np.add.at(f_ref, nodes[e], f_e)
    f_base, f_extra = np.zeros((n_base, 3)), np.zeros((len(X) - n_base, 3))
    subelements = SubelementSet(nodes, rule_of_element, packed)
    energy = add_subelement_forces(
        subelements, X[:n_base], X[n_base:], U[:n_base], U[n_base:], f_base, f_extra, finite
    )
    f = np.vstack([f_base, f_extra])
    assert energy == pytest.approx(energy_ref, rel=1e-13)
    np.testing.assert_allclose(f, f_ref, rtol=0, atol=1e-12 * np.abs(f_ref).max())


def test_lane_order_groups_rules_and_keeps_order_within_a_rule():
    rule_of_element = np.array([2, 0, 1, 0, 2, 2, 1, 0])
    order = batched.lane_order(rule_of_element)
    assert order.tolist() == [1, 3, 7, 2, 6, 0, 4, 5]
    assert order.dtype == np.int64


def test_batches_longer_than_the_lanes_split_and_rules_do_not_mix():
    """A run of one rule longer than LANES, between runs of others: the same forces as element
    by element (a batch mixing two rules would use one rule's points for both)."""
    rng = np.random.default_rng(5)
    rules = _rules(rng)
    packed = se.concatenate_rules(rules)
    ne = 2 * batched.LANES + 3
    rule_of_element = np.array([1] * 3 + [2] * (2 * batched.LANES - 1) + [1], dtype=np.int64)
    nodes = np.arange(8 * ne, dtype=np.int32).reshape(ne, 8)
    X = np.vstack([distorted_hex(rng) for _ in range(ne)])
    U = rng.normal(scale=1e-3, size=X.shape)
    f_base, f_extra = np.zeros_like(X), np.zeros((0, 3))
    add_subelement_forces(
        SubelementSet(nodes, rule_of_element, packed), X, f_extra, U, f_extra, f_base, f_extra
    )
    for e in range(ne):
        f_e = np.empty((8, 3))
        se.solid_shell_force(X[nodes[e]], U[nodes[e]], *rules[rule_of_element[e]], f_e)
        np.testing.assert_allclose(f_base[nodes[e]], f_e, rtol=0, atol=1e-12 * np.abs(f_e).max())
