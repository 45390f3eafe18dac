"""Ply materials and laminates, intralaminar ply damage, the cohesive law of the interfaces."""
