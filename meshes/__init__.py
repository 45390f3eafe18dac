"""Gmsh mesh generators (flat laminated beams and plates) that hand their meshes to DOLFINx."""

# mpi4py first: the DOLFINx wheel finds libmpi through it.
from fenics_adaptive.meshes.beam import BeamMesh, esl_mesh, layered_mesh
from mpi4py import MPI  # noqa: F401

__all__ = ["BeamMesh", "esl_mesh", "layered_mesh"]
