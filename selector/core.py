"""The selector (paper, Controller Selection): pi_Omega(s) = argmax_w E[ 1_{I_w}(s) * G(D_w^n(s)) ].

Generic over the state type: a state is any tensor row, so the same code selects with tabular models in
the random-walk MDP and with latent MDN models in the gear task. Each candidate's expectation is estimated
from K sampled n-step rollouts of its dynamics model, batched over decisions and samples.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import torch


class DynamicsModel(Protocol):
    """D_w: one sampled step of the state under controller w."""

    def step(self, states: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(M, *S) -> (M, *S)."""


class GoalScore(Protocol):
    """G: estimated task progress in [0, 1] (0: a demonstration's first frame, 1: its last)."""

    def score(self, states: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """(M, *S) -> (M,)."""


@dataclass
class Decision:
    names: tuple[str, ...]
    choice: torch.Tensor  # (B,) index into names; -1 where no controller may start
    scores: torch.Tensor  # (B, W) mean predicted goal score; -inf outside the initiation set
    predicted: torch.Tensor | None = None  # (B, W, K, *S) sampled end states, if kept
    broken: torch.Tensor | None = None  # (B, W) applicable, but its predicted score is not finite: never chosen

    def chosen(self, b: int = 0) -> str | None:
        c = int(self.choice[b])
        return None if c < 0 else self.names[c]

    def log(self, b: int = 0) -> dict:
        """One decision as a plain record: the choice and every candidate's score (None: not applicable)."""
        scores = {n: (round(float(s), 6) if torch.isfinite(s) else None) for n, s in zip(self.names, self.scores[b])}
        broken = [] if self.broken is None else [n for n, x in zip(self.names, self.broken[b]) if x]
        return {"choice": self.chosen(b), "scores": scores, **({"not_finite": broken} if broken else {})}


class Selector:
    def __init__(self, dynamics: Mapping[str, DynamicsModel], goal: GoalScore, horizon: int = 10, samples: int = 16,
                 seed: int | None = None, keep_predictions: bool = False):
        if horizon < 1 or samples < 1:
            raise ValueError(f"horizon and samples must be >= 1, got horizon={horizon}, samples={samples}")
        if not dynamics:
            raise ValueError("the selector needs at least one controller's dynamics model")
        self.names = tuple(dynamics)
        self.dynamics = dict(dynamics)
        self.goal = goal
        self.horizon = horizon
        self.samples = samples
        self.keep_predictions = keep_predictions
        self.generator = torch.Generator()
        self.generator.manual_seed(seed if seed is not None else torch.seed())

    def rollout(self, name: str, states: torch.Tensor) -> torch.Tensor:
        """D_w^n: K sampled n-step futures of each state, (B, *S) -> (B, K, *S)."""
        x = states.repeat_interleave(self.samples, dim=0)
        for _ in range(self.horizon):
            x = self.dynamics[name].step(x, self.generator)
        return x.view(states.shape[0], self.samples, *states.shape[1:])

    @torch.no_grad()
    def decide(self, states: torch.Tensor, applicable: torch.Tensor | None = None) -> Decision:
        """Score every applicable controller from each state (rows of `states`) and pick the best.

        `applicable[b, w]` is 1_{I_w}(s_b), evaluated by the caller on the real observation (a controller's
        initiation set lives in its own state space, not in the selector's).
        """
        B, W = states.shape[0], len(self.names)
        if applicable is None:
            applicable = torch.ones(B, W, dtype=torch.bool)
        if applicable.shape != (B, W):
            raise ValueError(f"applicable must be (batch, controllers) = ({B}, {W}), got {tuple(applicable.shape)}")
        scores, predicted = self.evaluate(states, applicable)
        broken = applicable & ~torch.isfinite(scores)  # a model that computes NaN or Inf: reported, not ranked
        choice = scores.masked_fill(broken, float("-inf")).argmax(dim=1)  # ties: the first in library order
        choice[~(applicable & ~broken).any(dim=1)] = -1
        return Decision(self.names, choice, scores, predicted, broken)

    def evaluate(self, states: torch.Tensor, applicable: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """E[G(D_w^n(s))] for every applicable (state, controller), -inf elsewhere, (B, W); and the sampled futures
        (B, W, K, *S) if kept. One controller at a time: any model of the protocols runs here."""
        B, W, K = states.shape[0], len(self.names), self.samples
        scores = torch.full((B, W), float("-inf"))
        predicted = torch.zeros(B, W, K, *states.shape[1:], dtype=states.dtype) if self.keep_predictions else None
        for w, name in enumerate(self.names):
            rows = applicable[:, w].nonzero().flatten()
            if len(rows) == 0:
                continue
            future = self.rollout(name, states[rows])
            g = self.goal.score(future.flatten(0, 1), self.generator).view(len(rows), K)
            scores[rows, w] = g.mean(dim=1).float()
            if predicted is not None:
                predicted[rows, w] = future
        return scores, predicted
