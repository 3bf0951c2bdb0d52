"""The paper's five random-walk controllers: c1-c3 go right (termination beta 0.2, 0.5, 0.9), c4 acts at random,
c5 goes left (beta 0.5).

The paper lists "beta = {0.9, 0.5, 0.2}" for policies 1-3, but its figure has policy 1 going furthest
(1 -> 6) and its optimum is "based on policy 1", which only holds if policy 1 terminates least often; so
here c1 has beta 0.2. The paper gives no beta for the random controller; c4 uses 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from policy_composer.policies.base import Controller
from policy_composer.tasks.random_walk.env import LEFT, RIGHT


@dataclass(frozen=True)
class RandomWalkOption:
    name: str
    direction: int | None  # RIGHT, LEFT, or None for a random action
    beta: float  # termination probability after each step


RANDOM_WALK_OPTIONS = (
    RandomWalkOption("c1", RIGHT, 0.2),
    RandomWalkOption("c2", RIGHT, 0.5),
    RandomWalkOption("c3", RIGHT, 0.9),
    RandomWalkOption("c4", None, 0.5),
    RandomWalkOption("c5", LEFT, 0.5),
)


class RandomWalkController(Controller):
    obs_keys = ("state",)
    action_kind = "discrete"
    initiation = "a non-terminal state"

    def __init__(self, option: RandomWalkOption, num_states: int):
        self.option = option
        self.name = option.name
        self.num_states = num_states
        self._rng = np.random.default_rng()

    def can_start(self, obs: int) -> bool:
        return 1 <= int(obs) <= self.num_states

    def reset(self, obs: int, seed: int | None = None) -> None:
        if seed is not None:
            self._rng = np.random.default_rng(seed)

    def act(self, obs: int) -> int:
        if self.option.direction is None:
            return int(self._rng.integers(2))
        return self.option.direction

    def done(self, obs: int) -> bool:
        return not self.can_start(obs) or bool(self._rng.random() < self.option.beta)

    def describe(self, obs: int) -> str:
        return f"state {int(obs)} of 0..{self.num_states + 1}"


def random_walk_controllers(num_states: int) -> list[RandomWalkController]:
    return [RandomWalkController(o, num_states) for o in RANDOM_WALK_OPTIONS]
