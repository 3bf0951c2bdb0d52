"""The controller library: options with a control law, an initiation set and a termination condition."""
