"""The one exception type for bad user input (configs, layups, mesh parameters)."""


class InputError(ValueError):
    """Bad user input. The message is one line that starts with the offending key, e.g.
    ``materials.carbon.E1: must be > 0 (got -1.0)``."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}" if key else problem)
