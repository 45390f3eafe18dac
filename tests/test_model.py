"""The base model's pre-packed force assembly (``model.PackedDisplacement``) against DOLFINx's
own packing and assembly.

Units: N, mm, s, tonne.
"""

import numpy as np
import pytest
from dolfinx import fem
from helpers import CROSS_PLY, esl_model


@pytest.mark.parametrize("kinematics", ["small", "finite"])
def test_packed_displacement_is_dolfinx_packing(kinematics):
    model = esl_model(CROSS_PLY, 6.0, 3.0, 6, 3, kinematics=kinematics)
    # part of the cells, as an adaptive model has after refinement: several cell sets
    owned = model.layer_cells(0)
    model.set_ufl_cells([owned[owned % 3 != 0]])
    rng = np.random.default_rng(0)
    model.u.x.array[:] = rng.normal(scale=1e-2, size=model.u.x.array.shape)

    packed = model.packed
    model.update_coefficients()  # u and the condensed enhanced thickness strain
    for i, form in enumerate((model.force_form, model.energy_form)):
        reference = fem.pack_coefficients(form)
        assert set(packed.coeffs[i]) == set(reference)
        for key, values in reference.items():
            # DOLFINx packs zeros for a coefficient an integral does not read (the enhanced
            # field in the shear terms); the shared array holds it for every integral
            reads_field = np.any(values[:, 24:])
            columns = slice(None) if reads_field else slice(0, 24)
            np.testing.assert_array_equal(packed.coeffs[i][key][:, columns], values[:, columns])
        assert packed.coeffs[i][key].shape == values.shape
        np.testing.assert_array_equal(packed.constants[i], fem.pack_constants(form))
    # the energy through the pre-packed data equals DOLFINx's
    energy = fem.assemble_scalar(model.energy_form)
    assert energy > 0.0
    assert model.strain_energy() == pytest.approx(energy, rel=1e-13)

    # the force through the pre-packed data equals DOLFINx packing it itself
    mine = np.zeros_like(model.u.x.array)
    model.add_internal_force(mine)
    theirs = fem.assemble_vector(model.force_form).array
    assert np.abs(theirs).max() > 0.0
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-13 * np.abs(theirs).max())

    # and follows u: packing once per step is packing the current displacement
    model.u.x.array[:] *= -2.0
    mine = np.zeros_like(mine)
    model.add_internal_force(mine)
    theirs = fem.assemble_vector(model.force_form).array
    np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-13 * np.abs(theirs).max())
