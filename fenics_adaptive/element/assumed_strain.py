"""Assumed natural thickness strain of the solid shell on curved cells (trapezoidal locking).

Units: none (strains); the kernels' mm and MPa pass through.

Why. On a curved shell the vertical edges ("directors", d x / d zeta) of a cell are not
parallel. The compatible covariant thickness strain E_zz = x,zeta . u,zeta (small strain) is
then the product of two fields bilinear in (xi, eta), and in bending the product carries a
spurious part quadratic in the in-plane coordinates: the element stiffens with the square of
(cell size / thickness x angle between its directors), the trapezoidal (curvature thickness)
locking of solid shells. Betsch and Stein (1995, Commun. Numer. Methods Eng. 11; as Bischoff
and Ramm 1997, Hauptmann and Schweizerhof 1998 use it) sample E_zz on the four vertical edges,
where it is exact, and interpolate bilinearly between them.

What is computed. With c_xi = xi (1 - xi), c_eta = eta (1 - eta), the edge-sampled strain is the
compatible one plus

    dE = c_xi a,xi . b,xi + c_eta a,eta . b,eta

for E_zz = a . b (small strain: a = X,zeta, b = u,zeta; finite: E_zz = 1/2 (x,zeta . x,zeta -
X,zeta . X,zeta) = (X,zeta + u,zeta / 2) . u,zeta, a = X,zeta + u,zeta / 2). dE vanishes on the
four edges and removes the quadratic variation along xi and along eta: the strain is the sum of
the interpolations along xi and along eta less the compatible one, which is Betsch and Stein's
bilinear interpolation less c_xi c_eta a,xi eta . b,xi eta: their twist term is left out. It is
zero where the directors are not twisted (a,xi eta = 0: flat, cylindrical and conical cells, a
tube, a panel, the fillets of a hat section) and of higher order elsewhere; the UFL form could
reach it only through a third derivative of u on a non-affine cell, whose form takes about 90 s
to compile (the rest, 10 s). The covariant correction enters the Cartesian strain of the cell's
frame as dE k (x) k, k = grad zeta (the third row of J^-1): every point of every energy term
gets it, and the stress does work through the derivative of dE. The price of any such
interpolation: a uniform strain is no longer reproduced exactly on a cell whose directors turn
by an angle t, its thickness strain being off by t^2 / 6 of the strain along the turn (a tube
of 72 cells round: 0.13 %).

Where. Only on cells whose directors are not parallel (``directors_bend``): on the flat meshes'
cells dE is zero under small strain, and under finite kinematics the flat cells keep their
compatible thickness strain, as before (there dE would be the b . b terms alone, second order
in the displacement gradient: a flat laminate bent into a curve). The UFL form
(``solid_shell.strain_energy_form``) and the numba kernels (``subelement``, ``batched``,
``adaptivity.ply_fields``) compute the same dE, to round-off.

Cost. A curved cell pays a dozen multiply-adds per point and per line, and five dot products
and the forces of three monomials once per cell (below); a flat cell one test, or, in a batch
of the batched kernel that holds a curved cell, the curved cell's work. The batched
elastic kernel: 0.45 us per cell of a tube, 0.41 us with the same cells' edges parallel
(``benchmarks/run.py --only kernels``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# directors parallel below this relative size of their in-plane derivatives (round-off of a
# flat cell is 1e-16; a 90 degree arc of 64 cells turns its directors by 2.5e-2)
DIRECTOR_TOLERANCE = 1.0e-9


@njit(inline="always")
def directors_bend(bx):
    """Whether a cell's directors x,zeta are not parallel, from the monomial coefficients ``bx``
    (8, 3) of its vertex coordinates (``subelement._monomials``): x,zeta xi, x,zeta eta or
    x,zeta xi eta (rows 5, 6, 7) beyond ``DIRECTOR_TOLERANCE`` of x,zeta (row 4)."""
    bend = 0.0
    size = 0.0
    for i in range(3):
        bend += bx[5, i] * bx[5, i] + bx[6, i] * bx[6, i] + bx[7, i] * bx[7, i]
        size += bx[4, i] * bx[4, i]
    return bend > DIRECTOR_TOLERANCE * DIRECTOR_TOLERANCE * size


def cells_with_bent_directors(X: np.ndarray) -> np.ndarray:
    """(n,) bool: ``directors_bend`` of hexahedra with vertices X (n, 8, 3) (mm), the same test
    in numpy (the UFL form's cell marker)."""
    X = np.asarray(X, dtype=np.float64)
    edge = X[:, 4:] - X[:, :4]  # x,zeta on the four vertical edges, tensor order
    rows = (
        edge[:, 0],  # row 4: x,zeta at xi = eta = 0
        edge[:, 1] - edge[:, 0],  # row 5
        edge[:, 2] - edge[:, 0],  # row 6
        edge[:, 3] - edge[:, 2] - edge[:, 1] + edge[:, 0],  # row 7
    )
    size = np.einsum("ni,ni->n", rows[0], rows[0])
    bend = sum(np.einsum("ni,ni->n", r, r) for r in rows[1:])
    return bend > DIRECTOR_TOLERANCE**2 * size


# How the kernels evaluate it. With a = X,zeta (small strain) or X,zeta + u,zeta / 2 (finite,
# E_zz = (X,zeta + u,zeta / 2) . u,zeta) and b = u,zeta, both bilinear in (xi, eta) with
# monomial coefficients a_5 + eta a_7 = a,xi and a_6 + xi a_7 = a,eta (likewise b),
#
#   dE = c_xi (s55 + eta s57 + eta^2 s77) + c_eta (s66 + xi s67 + xi^2 s77),
#
# five dot products per cell ("strain coefficients": s55 = a5.b5, s57 = a5.b7 + a7.b5,
# s77 = a7.b7, s66 = a6.b6, s67 = a6.b7 + a7.b6), a dozen flops per line. Its derivative with
# respect to u's monomial coefficients 5, 6, 7 is c_xi g,xi, c_eta g,eta and
# eta c_xi g,xi + xi c_eta g,eta, g the current director X,zeta + u,zeta (finite) or X,zeta:
# the force T dE/d u summed over the lines of a cell needs only the six sums of T c_xi,
# T c_xi eta, T c_xi eta^2, T c_eta, T c_eta xi and T c_eta xi^2 ("work weights"), turned
# into forces once per cell (``correction_forces``).


@njit(inline="always")
def strain_coefficients(a5, a6, a7, b5, b6, b7):
    """One Cartesian component's share of the five strain coefficients (comment above) from
    that component of a's and b's monomial coefficients 5, 6, 7."""
    return (
        a5 * b5,
        a5 * b7 + a7 * b5,
        a7 * b7,
        a6 * b6,
        a6 * b7 + a7 * b6,
    )


@njit(inline="always")
def cell_strain_coefficients(bx, bu, finite):
    """The five strain coefficients of a cell from the monomial coefficients ``bx``, ``bu``
    (8, 3) of its reference coordinates and displacement."""
    s = (0.0, 0.0, 0.0, 0.0, 0.0)
    for i in range(3):
        half = 0.5 if finite else 0.0
        c = strain_coefficients(
            bx[5, i] + half * bu[5, i],
            bx[6, i] + half * bu[6, i],
            bx[7, i] + half * bu[7, i],
            bu[5, i],
            bu[6, i],
            bu[7, i],
        )
        s = (s[0] + c[0], s[1] + c[1], s[2] + c[2], s[3] + c[3], s[4] + c[4])
    return s


@njit(inline="always")
def edge_sampled_strain(s55, s57, s77, s66, s67, xi, eta):
    """dE on the vertical line (xi, eta) from a cell's five strain coefficients."""
    c_xi = xi * (1.0 - xi)
    c_eta = eta * (1.0 - eta)
    return c_xi * (s55 + eta * (s57 + eta * s77)) + c_eta * (s66 + xi * (s67 + xi * s77))


@njit(inline="always")
def work_weights(T, xi, eta):
    """A line's share of the six work weights (comment above), T its sum of
    w |det J| sigma : k k (``stress_on_director``)."""
    a = T * xi * (1.0 - xi)
    b = T * eta * (1.0 - eta)
    return a, a * eta, a * eta * eta, b, b * xi, b * xi * xi


@njit(inline="always")
def correction_forces(g5, g6, g7, W):
    """One component's force on u's monomial coefficients 5, 6, 7 from the cell's work weights
    ``W`` and that component of the director's monomial coefficients g (X,zeta, or X,zeta +
    u,zeta under finite strain)."""
    f5 = g5 * W[0] + g7 * W[1]
    f6 = g6 * W[3] + g7 * W[4]
    f7 = g5 * W[1] + g7 * W[2] + g6 * W[4] + g7 * W[5]
    return f5, f6, f7


@njit(inline="always")
def add_correction_forces(f_out, bx, bu, W, finite):
    """Add the cell's force through dE (work weights ``W``) to the derivatives ``f_out`` (8, 3)
    with respect to u's monomial coefficients."""
    for i in range(3):
        full = 1.0 if finite else 0.0
        f5, f6, f7 = correction_forces(
            bx[5, i] + full * bu[5, i],
            bx[6, i] + full * bu[6, i],
            bx[7, i] + full * bu[7, i],
            W,
        )
        f_out[5, i] += f5
        f_out[6, i] += f6
        f_out[7, i] += f7


@njit(inline="always")
def corrected_strain(strain, dE, K):
    """``strain`` (6-tuple, Voigt, engineering shears) plus dE k (x) k, k the third row of the
    row-major inverse Jacobian ``K`` (9-tuple)."""
    k0 = K[6]
    k1 = K[7]
    k2 = K[8]
    exx, eyy, ezz, gyz, gxz, gxy = strain
    return (
        exx + dE * k0 * k0,
        eyy + dE * k1 * k1,
        ezz + dE * k2 * k2,
        gyz + 2.0 * dE * k1 * k2,
        gxz + 2.0 * dE * k0 * k2,
        gxy + 2.0 * dE * k0 * k1,
    )


@njit(inline="always")
def stress_on_director(P, K):
    """w |det J| sigma : k (x) k, the stress's work-conjugate of dE (k as in
    ``corrected_strain``), from the point's P = w |det J| sigma J^-T (row-major 9-tuple,
    P[i, r] = sum_j sigma_ij K[r, j], before any F: the second Piola-Kirchhoff stress's under
    finite strain): sum_i k_i P[i, 2]."""
    return K[6] * P[2] + K[7] * P[5] + K[8] * P[8]
