"""What the controllers know of the task's state: the task's predicates (a part grasped, at the hole, inserted, ...)
at one observation, from which every initiation set, termination and guard of the library is made.

A `Senses` turns an observation into a `Percept`. The library's controllers are given one: `LearnedSenses`
(selector/predicates.py), classifiers of the cameras and joints trained on the recordings' labels, as a robot would
have them; or `OracleSenses`, the simulator's truth standing in for perception (privileged: for recording the
datasets and for the oracle's side of the figures).
"""

from __future__ import annotations

from typing import Protocol

from policy_composer.tasks.base import THRESHOLD, Percept
from policy_composer.tasks.registry import task_of

__all__ = ["THRESHOLD", "CachedSenses", "OracleSenses", "Percept", "Senses"]


class Senses(Protocol):
    source: str

    def __call__(self, obs) -> Percept: ...


class CachedSenses:
    """A Senses that perceives each observation once, however many controllers and guards ask about it (the
    observation is kept, so its identity is not reused while it is the last one; None is perceived each time)."""

    source = ""

    def __init__(self):
        self._last: tuple[object, Percept] | None = None

    def __call__(self, obs) -> Percept:
        if obs is None or self._last is None or self._last[0] is not obs:
            self._last = (obs, self.perceive(obs))
        return self._last[1]

    def perceive(self, obs) -> Percept:
        raise NotImplementedError


class OracleSenses(CachedSenses):
    """The predicates from the simulator's truth (the task's `truth`): privileged, not a robot's."""

    source = "oracle"

    def __init__(self, env):
        super().__init__()
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.task = task_of(self.env)

    def perceive(self, obs) -> Percept:
        flags = self.task.truth(self.env)
        return Percept({name: float(flags[name][0]) for name in self.task.spec.predicates}, self.source)
