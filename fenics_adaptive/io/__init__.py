"""Files of a run: checkpoints, history and fields, the run folder."""
