"""Run configuration as data: the schema of every key, parsing and checks, and the settings types
a config is made of (``kinds``: enums of the kinds and states; ``materials``: ply failure data and
the cohesive law; ``loads``: time curves, motions, face loads, the impactor; ``adaptivity``:
interfaces, stabilisation, indicators, manual refinements; ``solver``: solver and probe settings).
Standard library and numpy only: reading and checking a config loads neither DOLFINx nor numba."""
