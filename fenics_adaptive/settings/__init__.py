"""Run configuration as data: the schema of every key, parsing and checks."""
