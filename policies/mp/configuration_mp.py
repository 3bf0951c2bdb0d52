"""Configuration of the motion-planning controllers (light: the command line reads it without importing OMPL)."""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.policies.registry import register_kind


@register_kind("mp", label="MP", subtasks=("pick", "move", "insert", "regrasp"), planned=True)
@dataclass
class MPConfig:
    # Collision checks one RRT-Connect plan may spend (about 4 s here): a work budget, not a time budget, so that a
    # busy machine plans the same paths, only slower.
    plan_checks: int = 20_000
    speed: float = 0.4  # planned paths run at this fraction of the joint velocity limits
