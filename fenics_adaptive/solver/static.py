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

from fenics_adaptive.model.forms import CondensedThicknessStrain, LayeredModel
from fenics_adaptive.model.loading import COMPONENTS, PrescribedMotion, ResolvedLoads, face_dofs


def stiffness_form(model: LayeredModel) -> ufl.Form:
    """Tangent stiffness K_uu (bilinear form) of the model's internal force at fixed enhanced
    thickness strain; ``stiffness_matrix`` condenses the enhanced strain out of it."""
    model.forms_ready()
    return ufl.derivative(model.force_ufl, model.u, ufl.TrialFunction(model.V))


def stiffness_matrix(model: LayeredModel) -> PETSc.Mat:
    """The tangent stiffness (N/mm) of the UFL cells at the current displacement, the enhanced
    thickness strain condensed (``forms.CondensedThicknessStrain``): K = K_uu - K_ua P K_au,
    P = T h^-1 T^T cell by cell on the enhanced field's values (K_au = K_ua^T, the energy's
    mixed second derivative)."""
    model.update_coefficients()  # the enhanced field at the current u
    K = fem_petsc.assemble_matrix(fem.form(stiffness_form(model)))
    K.assemble()
    enhanced = model.enhanced
    if enhanced is None:
        return K
    if enhanced.linear_maps is not None:  # the assembled condensation knows h
        enhanced = CondensedThicknessStrain(
            model.energy_ufl,
            enhanced.field,
            model.u,
            model.V,
            enhanced.cells,
            frame=model.frame,
            bent=model.bent,
        )
    A = enhanced.field.function_space
    K_ua = fem_petsc.assemble_matrix(
        fem.form(ufl.derivative(model.force_ufl, enhanced.field, ufl.TrialFunction(A)))
    )
    K_ua.assemble()
    # P block by block in CSR (an owned cell's DG dofs are owned): row = the cell's dof i,
    # columns = its 8 dofs
    index_map = A.dofmap.index_map
    n_local, n_global = index_map.size_local, index_map.size_global
    dofs = enhanced.cell_dofs
    blocks = np.einsum("ik,rk,jk->rij", enhanced.T, 1.0 / enhanced.h, enhanced.T)
    columns = index_map.local_to_global(dofs.astype(np.int32).ravel()).reshape(dofs.shape)
    rows = np.broadcast_to(dofs[:, :, None], blocks.shape).ravel()
    order = np.argsort(rows, kind="stable")
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n_local))])
    P = PETSc.Mat().createAIJ(
        ((n_local, n_global), (n_local, n_global)),
        csr=(
            indptr.astype(PETSc.IntType),
            np.broadcast_to(columns[:, None, :], blocks.shape).ravel()[order].astype(PETSc.IntType),
            blocks.ravel()[order],
        ),
        comm=model.comm,
    )
    P.assemble()
    correction = K_ua.matMult(P).matMult(K_ua.transpose())
    K.axpy(-1.0, correction, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    for matrix in (K_ua, P, correction):
        matrix.destroy()
    return K


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
    A = stiffness_matrix(model)

    rhs = fem.Function(V)
    loads.external_force(t, rhs.x.array)
    rhs.x.array[model.n_owned_dofs :] = 0.0  # ghosts are added back by the reverse scatter
    b = rhs.x.petsc_vec
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    prescribed = fem.Function(V)
    fem_petsc.set_bc(prescribed.x.petsc_vec, bcs)
    # b -= A g on the free rows, b = g on the prescribed ones (symmetric elimination)
    owned = [bc.dof_indices()[0][: bc.dof_indices()[1]] for bc in bcs]
    local = np.unique(np.concatenate(owned)) if owned else np.zeros(0, np.int32)
    index_map = V.dofmap.index_map
    rows = 3 * index_map.local_to_global((local // 3).astype(np.int32)) + local % 3
    A.zeroRowsColumns(rows.astype(PETSc.IntType), 1.0, prescribed.x.petsc_vec, b)

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
