"""The layered solid-shell element: integration rules, UFL forms, numba kernels, stable step."""
