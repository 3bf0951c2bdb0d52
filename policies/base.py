"""The controller interface of the library: an option (paper, Method) with its own state space, action space and rate.

A controller `c_w` has a control law `pi_w` (`act`), an initiation set `I_w` (`can_start`) and a termination
condition `beta_w` (`done`). It reads only its own observation keys and knows nothing of the selector, so
controllers of very different kinds (a motion planner, a DMP, a CNN, a LeRobot policy, a tabular option) sit
in one library. To add one, subclass `Controller`, fill the class attributes and the three methods.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any


class InitiationError(RuntimeError):
    """A controller was asked to start outside its initiation set."""


class Controller(ABC):
    name: str = "controller"
    obs_keys: tuple[str, ...] = ()  # the parts of the observation this controller reads: its state space
    action_kind: str = ""  # e.g. "discrete", "joint_targets", "joint_waypoints"
    rate_hz: float | None = None  # how often it acts; None: once per env step
    initiation: str = "anywhere"  # I_w in words, for error messages and the controller table in docs/controllers.md

    @abstractmethod
    def can_start(self, obs: Any) -> bool:
        """Whether `obs` is in the initiation set I_w."""

    @abstractmethod
    def act(self, obs: Any) -> Any:
        """The control law pi_w: the next action, in this controller's action space."""

    @abstractmethod
    def done(self, obs: Any) -> bool:
        """The termination condition beta_w, checked after every step (may be stochastic)."""

    def reset(self, obs: Any, seed: int | None = None) -> None:  # noqa: B027  (an optional hook)
        """Prepare an activation from `obs` (plan, fit, clear memory). Called by `start` only."""

    def start(self, obs: Any, seed: int | None = None) -> None:
        """Begin an activation; refuse with InitiationError outside the initiation set."""
        if not self.can_start(obs):
            raise InitiationError(f"controller {self.name} cannot start here: its initiation set is "
                                  f"'{self.initiation}' ({self.describe(obs)})")
        self.reset(obs, seed)

    def describe(self, obs: Any) -> str:
        """A short account of `obs` in this controller's own terms (used in errors)."""
        return f"observation {obs!r}"
