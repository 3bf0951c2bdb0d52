"""The selector over a task's latent dynamics models, in one pass per decision.

Every controller's K rollouts step together through `StackedDynamics`, and the futures of every applicable
controller decode and score as one batch. The random draws of a decision are fixed per controller, state, sample
and step before any model runs, so the scores do not depend on how the work is batched: rolling out and scoring
one controller at a time (`batched=False`, the reference) gives the same scores within float tolerance.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from policy_composer.selector.core import GoalScore, Selector
from policy_composer.selector.dynamics import LatentDynamics, StackedDynamics


class LatentSelector(Selector):
    def __init__(self, dynamics: Mapping[str, LatentDynamics], goal: GoalScore, horizon: int = 10,
                 samples: int = 16, seed: int | None = None, keep_predictions: bool = False, batched: bool = True):
        super().__init__(dynamics, goal, horizon, samples, seed, keep_predictions)
        models = list(self.dynamics.values())
        # Models of different shapes (a controller trained at other sizes) step one at a time, the reference way.
        self.stack = StackedDynamics(models) if batched and StackedDynamics.stackable(models) else None

    def draws(self, batch: int, latent_dim: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The decision's random numbers: uniforms (W, n, B, K) that pick mixture components, normals (..., L)."""
        shape = (len(self.names), self.horizon, batch, self.samples)
        return (torch.rand(shape, generator=self.generator),
                torch.randn(*shape, latent_dim, generator=self.generator))

    def futures(self, states: torch.Tensor, applicable: torch.Tensor) -> torch.Tensor:
        """D_w^n of the states under the controllers that may start, (B, L) -> (B, W, K, L); zeros for controllers
        applicable to no state (and, one controller at a time, for the states it is not applicable to)."""
        (B, L), W, K = states.shape, len(self.names), self.samples
        u, noise = self.draws(B, L)
        out = torch.zeros(B, W, K, L)
        if self.stack is not None:
            active = applicable.any(dim=0).nonzero().flatten()  # controllers that may start from some state
            stack = self.stack if len(active) == W else self.stack.select(active)
            z = states.repeat_interleave(K, dim=0).expand(len(active), B * K, L)
            for t in range(self.horizon):
                z = stack.step(z, (u[active, t].flatten(1), noise[active, t].flatten(1, 2)))
            out[:, active] = z.view(len(active), B, K, L).transpose(0, 1)
            return out
        for w, name in enumerate(self.names):
            rows = applicable[:, w].nonzero().flatten()
            z = states[rows].repeat_interleave(K, dim=0)
            for t in range(self.horizon):
                z = self.dynamics[name].step(z, draws=(u[w, t, rows].flatten(), noise[w, t, rows].flatten(0, 1)))
            out[rows, w] = z.view(len(rows), K, L)
        return out

    def evaluate(self, states: torch.Tensor, applicable: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        futures = self.futures(states, applicable)
        scores = torch.full(applicable.shape, float("-inf"))
        if self.stack is not None:
            picked = futures[applicable]  # (R, K, L): all applicable futures, one pass through decoder and scorer
            scores[applicable] = self.goal.score(picked.flatten(0, 1), self.generator).view(-1, self.samples).mean(1)
        else:
            for w in range(len(self.names)):
                rows = applicable[:, w]
                if rows.any():
                    g = self.goal.score(futures[rows, w].flatten(0, 1), self.generator)
                    scores[rows, w] = g.view(-1, self.samples).mean(1)
        predicted = futures * applicable[:, :, None, None] if self.keep_predictions else None
        return scores, predicted
