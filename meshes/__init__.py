"""Gmsh mesh generators that hand their meshes to DOLFINx: flat laminated beams and plates
(``beam``), and shells: quadrilateral surfaces generated or read from a file (``surface``)
extruded along their normals into solid shells with a frame per cell (``shell``)."""

# mpi4py first: the DOLFINx wheel finds libmpi through it.
from mpi4py import MPI  # noqa: F401, I001

from fenics_adaptive.meshes.beam import BeamMesh, esl_mesh, layered_mesh
from fenics_adaptive.meshes.shell import ShellMesh, shell_mesh
from fenics_adaptive.meshes.surface import SurfaceMesh, read_surface, shell_surface, write_surface

__all__ = [
    "BeamMesh",
    "ShellMesh",
    "SurfaceMesh",
    "esl_mesh",
    "layered_mesh",
    "read_surface",
    "shell_mesh",
    "shell_surface",
    "write_surface",
]
