"""The learning kernel's errors that the command line reports in one line: here, apart from the modules that raise
them, so that the command line catches them without importing torch."""


class CheckpointError(ValueError):
    """A checkpoint that is missing, of another kind of model, or from another configuration."""


class TrainingDiverged(ValueError):
    """A loss that is not finite: every weight after it would be noise, so the training stops and saves nothing."""
