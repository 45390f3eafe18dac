"""fenics-adaptive: the adaptive thick-shell element for explicit dynamics of laminates, on FEniCSx.

Units throughout: N, mm, s, tonne (stress MPa, density tonne/mm^3, energy mJ = N mm).

The public API is the names below (``docs/api.md`` walks through them with a checked example):

- ``load_config(path)``, ``parse_config(data)``: a config (TOML file or dict) as a checked
  ``RunConfig``; reading one loads neither DOLFINx nor numba;
- ``Simulation(config)``: the model built and ready; ``run()`` it to the end, or ``start()``
  and ``step()`` it owning the loop, reading ``t``, ``u``, ``v``, forces, ``history`` and
  ``interface_state`` between steps; ``add_indicator`` (a ``PythonIndicator``) and
  ``add_observer`` (an ``Observer``, told of each ``HistoryRow`` and ``RefinementEvent``),
  ``add_contributor`` (a force of one's own: a ``Contributor`` of a ``ForceKind``);
- ``InterfaceState``: NONE / WEAK / STRONG, the refinement state of a cell's interface;
- ``run_config(config, out_dir)``: what ``fenics-adaptive run`` does (a run folder with the
  history, fields, checkpoints, summary and plots);
- ``InputError``: what every bad input raises (``key: problem``).

The names are imported on first use, so that ``import fenics_adaptive`` (and
``fenics-adaptive --help``) stays fast.
"""

from importlib import import_module

# mpi4py first: the DOLFINx wheel finds libmpi through it, whatever order modules import in
# (a script of one's own that imports dolfinx before anything else must do the same). Without
# it (an install without DOLFINx's stack) the package still imports: the command line then says
# what is missing (``cli.missing_runtime``).
try:
    from mpi4py import MPI  # noqa: F401
except ImportError:
    pass

__version__ = "0.1.0"

# public name -> the module that defines it
_PUBLIC = {
    "load_config": "fenics_adaptive.settings.config",
    "parse_config": "fenics_adaptive.settings.config",
    "RunConfig": "fenics_adaptive.settings.config",
    "InterfaceState": "fenics_adaptive.settings.kinds",
    "Simulation": "fenics_adaptive.simulation",
    "PythonIndicator": "fenics_adaptive.simulation",
    "Observer": "fenics_adaptive.solver.observers",
    "Contributor": "fenics_adaptive.model.forces",
    "ForceKind": "fenics_adaptive.model.forces",
    "HistoryRow": "fenics_adaptive.solver.explicit",
    "RefinementEvent": "fenics_adaptive.adaptivity.events",
    "run_config": "fenics_adaptive.runner",
    "InputError": "fenics_adaptive.errors",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'fenics_adaptive' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value  # once imported, a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_PUBLIC})
