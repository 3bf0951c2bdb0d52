"""The learning kernel every model of the project builds on: checkpoints, the training loop, shared layers."""
