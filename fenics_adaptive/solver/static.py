"""Linear static solution of the small-strain model: K u = f_ext with the prescribed motions as
Dirichlet conditions, solved directly (LU). An independent path to the explicit solver's
quasi-static answer, and the reference for element tests.

Units: N, mm.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc
from petsc4py import PETSc

from fenics_adaptive.model.forms import LayeredModel
from fenics_adaptive.model.loading import COMPONENTS, PrescribedMotion, ResolvedLoads, face_dofs


def stiffness_form(model: LayeredModel) -> ufl.Form:
    """Tangent stiffness K (bilinear form) of the model's internal force."""
    return ufl.derivative(model.force_ufl, model.u, ufl.TrialFunction(model.V))


def solve_static(
    model: LayeredModel,
    motions: Sequence[PrescribedMotion],
    loads: ResolvedLoads,
    t: float,
) -> np.ndarray:
    """Displacement (owned + ghost entries, mm) in equilibrium with the loads and prescribed
    displacements at time t. Also left in ``model.u``."""
    V = model.V
    bcs = [
        fem.dirichletbc(
            motion.displacement(t),
            face_dofs(
                model, motion.face, motion.component, owned_only=False, x_range=motion.x_range
            ),
            V.sub(COMPONENTS[motion.component]),
        )
        for motion in motions
    ]

    model.u.x.array[:] = 0.0
    a = fem.form(stiffness_form(model))
    A = fem_petsc.assemble_matrix(a, bcs=bcs)
    A.assemble()

    rhs = fem.Function(V)
    loads.external_force(t, rhs.x.array)
    rhs.x.array[model.n_owned_dofs :] = 0.0  # ghosts are added back by the reverse scatter
    b = rhs.x.petsc_vec
    fem_petsc.apply_lifting(b, [a], bcs=[bcs])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    fem_petsc.set_bc(b, bcs)

    ksp = PETSc.KSP().create(model.comm)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    if model.comm.size > 1:
        ksp.getPC().setFactorSolverType("mumps")
    ksp.solve(b, model.u.x.petsc_vec)
    model.u.x.scatter_forward()
    ksp.destroy()
    A.destroy()
    return model.u.x.array.copy()
