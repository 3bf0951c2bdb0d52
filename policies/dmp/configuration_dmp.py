"""Configuration of the DMP controllers and of the planner episodes they are fitted to (light: the command line
reads it without importing the planner)."""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.policies.registry import register_kind

# The planner episodes the DMPs are fitted to start at this seed, apart from the seeds they are evaluated on.
FIT_FIRST_SEED = 100
FIT_EPISODES = 5


@register_kind("dmp", label="DMP", subtasks=("pick", "move", "insert"), trained=True, planned=True)
@dataclass
class DMPConfig:
    n_weights_per_dim: int = 10
    dt: float = 0.05  # the env's control period
    speed: float = 0.4  # a movement never runs faster than this fraction of the joint velocity limits
    smooth_scaling: bool = True  # Pastor et al.: no jump when the new start differs from the demonstration's
