"""The application's errors that the command line reports in one line: here, apart from the modules that raise
them, so that the command line catches them without importing the simulator or torch."""


class RunError(ValueError):
    """A composed run that the command would overwrite, or continue with other settings than its own."""


class ClusterError(RuntimeError):
    """A Ray cluster that cannot be reached or used, or an address that names none."""
