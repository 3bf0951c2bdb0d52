"""Configuration of a LeRobot policy checkpoint as a controller (light: the command line reads it without LeRobot
or torch).

A checkpoint kind: its controllers are the checkpoints the user brings (`--lerobot PATH:SUBTASK[:NAME]`), each with
the subtask it was trained for, not one per subtask of the task; a checkpoint's config is its source.
"""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.policies.registry import register_kind


@register_kind("lerobot_policy", label="LeRobot", subtasks=(), checkpoints=True)
@dataclass(frozen=True)
class LeRobotSource:
    """A lerobot checkpoint to run as a controller for one subtask."""

    path: str
    subtask: str = "insert"
    name: str | None = None  # default: lerobot_<subtask>

    @property
    def controller_name(self) -> str:
        return self.name or f"lerobot_{self.subtask}"
