"""Explicit central-difference integration, the static reference solve, physics guards."""
