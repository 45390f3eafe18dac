"""The discrete model the solver integrates: forms, structure, loads, contact, assembly."""
