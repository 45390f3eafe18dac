"""The free vibration of a small structure, solved densely: its stiffness, lumped and scaled
mass matrices and the eigenvalues of K x = omega^2 M x, to measure what a scaled mass does to
the frequencies (``model.mass_scaling``; ``benchmarks/mass_scaling.py`` and the tests).

Units: N, mm, s, tonne (K in N/mm, M in tonne, eigenvalues in 1/s^2). One MPI rank; a model of
a few thousand DOFs (the matrices are dense).
"""

from __future__ import annotations

import math

import numpy as np

from fenics_adaptive.model.structure import Structure


def dense_system(structure: Structure) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, the lumped mass matrix, the scaled one) on the free base DOFs of ``structure``,
    which has a scaled mass (``structure.scaled_mass``). Column j of K is the internal force of
    a unit displacement of DOF j (small strain; symmetrised); the structure is left at rest."""
    n = len(structure.base_block.mass)
    free = np.setdiff1d(np.arange(n), structure.base_block.fixed)
    u = structure.base.u.x
    K, M = np.zeros((n, len(free))), np.zeros((n, len(free)))
    unit = np.zeros(n)
    for column, j in enumerate(free):
        u.array[:] = 0.0
        u.array[j] = 1.0
        structure.internal_force()
        K[:, column] = structure.f_base.array[:n]
        unit[:] = 0.0
        unit[j] = 1.0
        structure.scaled_mass.multiply(unit, M[:, column])
    u.array[:] = 0.0
    K = K[free]
    return 0.5 * (K + K.T), np.diag(structure.base_block.mass[free]), M[free]


def eigenvalues(K: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The eigenvalues omega^2 (1/s^2, ascending) of K x = omega^2 M x, M positive definite."""
    L_inv = np.linalg.inv(np.linalg.cholesky(M))
    return np.linalg.eigvalsh(L_inv @ K @ L_inv.T)


def frequencies(K: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The frequencies (Hz, ascending) of K x = omega^2 M x."""
    return np.sqrt(np.maximum(eigenvalues(K, M), 0.0)) / (2 * math.pi)
