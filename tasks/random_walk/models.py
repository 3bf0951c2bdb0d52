"""Tabular dynamics and goal-score models of the random-walk MDP, exact or noisy (paper: "Simulated MDP").

The model state is a row (position, running): `running` is 1 while the controller is still active, so
chaining the one-step model n times (D^n) also models the controller's own termination beta.

Noise, exactly: each application of a dynamics model, with probability `p_wrong`, returns a wrong position
drawn uniformly from the other N+1 positions of 0..N+1 (the `running` flag is kept); the goal score, with
probability `p_wrong`, returns the value of a wrong position drawn the same way. With p_wrong = 0 both are
exact.
"""

from __future__ import annotations

import torch

from policy_composer.tasks.random_walk.controllers import RandomWalkOption
from policy_composer.tasks.random_walk.env import RIGHT


def _wrong_positions(pos: torch.Tensor, num_states: int, generator: torch.Generator) -> torch.Tensor:
    """Uniform over {0..N+1} without the given position."""
    r = torch.randint(0, num_states + 1, pos.shape, generator=generator)
    return r + (r >= pos).long()


def _corrupt(pos: torch.Tensor, p_wrong: float, num_states: int, generator: torch.Generator) -> torch.Tensor:
    if p_wrong <= 0:
        return pos
    wrong = torch.rand(pos.shape, generator=generator) < p_wrong
    return torch.where(wrong, _wrong_positions(pos, num_states, generator), pos)


def model_states(positions, running: bool = True) -> torch.Tensor:
    """(B,) positions -> (B, 2) model states."""
    pos = torch.as_tensor(positions, dtype=torch.long).reshape(-1)
    return torch.stack([pos, torch.full_like(pos, int(running))], dim=1)


class TabularDynamics:
    """D_w of one random-walk controller: move while running and non-terminal, then stop with probability beta."""

    def __init__(self, option: RandomWalkOption, num_states: int, p_wrong: float = 0.0):
        self.option, self.num_states, self.p_wrong = option, num_states, p_wrong

    def step(self, states: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        pos, running = states[:, 0], states[:, 1].bool()
        active = running & (pos > 0) & (pos <= self.num_states)
        if self.option.direction is None:
            move = torch.randint(0, 2, pos.shape, generator=generator) * 2 - 1
        else:
            move = torch.full_like(pos, 1 if self.option.direction == RIGHT else -1)
        pos = torch.where(active, pos + move, pos)
        stop = torch.rand(pos.shape, generator=generator) < self.option.beta
        running = active & ~stop & (pos > 0) & (pos <= self.num_states)
        pos = _corrupt(pos, self.p_wrong, self.num_states, generator)
        return torch.stack([pos, running.long()], dim=1)


class TabularGoalScore:
    """G(s) = position / (N+1): 0 at the left terminal, 1 at the goal."""

    def __init__(self, num_states: int, p_wrong: float = 0.0):
        self.num_states, self.p_wrong = num_states, p_wrong

    def score(self, states: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        pos = _corrupt(states[:, 0], self.p_wrong, self.num_states, generator)
        return pos.float() / (self.num_states + 1)
