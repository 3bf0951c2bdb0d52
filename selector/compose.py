"""Composition inside ManiSkill rollouts: the selector runs a task's library with no fixed sequence.

At each decision it scores every controller whose initiation set holds the current state, runs the best one,
and decides again when it terminates (succeeded, failed, or stopped for safety) and, optionally, every
`reselect_every` control steps. `Eligibility` leaves out a controller that has just succeeded and one that has
failed `max_failures` times since the last success or `episode_failures` times in the episode. The episode ends
when no controller may start (the task is done, or nothing applies) or at `max_steps`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import torch

from policy_composer.policies.base import Controller
from policy_composer.policies.mp.planning import PlanningError
from policy_composer.selector.configuration import ComposeConfig
from policy_composer.selector.world_model import WorldModel
from policy_composer.tasks.registry import task_of


@dataclass
class Activation:
    controller: str
    start_step: int
    steps: int = 0
    outcome: str = "running"
    reason: str = ""
    subtask: str = ""  # the part of the task the controller serves ("" for one without a subtask)
    part: str = ""  # where the task's part was when it ended, from the simulator's truth: the log's, never a sense


@dataclass
class ComposedEpisode:
    seed: int
    success: bool = False
    steps: int = 0
    knocked_out: bool = False
    activations: list[Activation] = field(default_factory=list)
    decisions: list[dict] = field(default_factory=list)  # step, choice and every candidate's score
    reached: int = 0  # the furthest stage the task reached (1 picked, 2 at the pre-insertion pose, 3 seated)
    ended: str = ""  # "task done", "nothing applicable" or "out of steps"
    part: str = ""  # where the task's part was at the end (its `whereabouts`)

    @property
    def sequence(self) -> list[str]:
        return [a.controller for a in self.activations]

    def to_dict(self) -> dict:
        return {**asdict(self), "sequence": self.sequence}

    @classmethod
    def from_dict(cls, d: dict) -> ComposedEpisode:
        return cls(d["seed"], d["success"], d["steps"], d["knocked_out"], [Activation(**a) for a in d["activations"]],
                   d["decisions"], d.get("reached", 0), d.get("ended", ""),
                   d.get("part", d.get("gear", "")))


class Eligibility:
    """Which controllers may be chosen besides their initiation sets, from what the episode has seen so far.

    A controller that has just succeeded sits out the next decision: its subtask is done, and where the next
    subtask's initiation set and its own overlap (a part at the edge of the pre-insertion pose) re-running it would
    only repeat itself. A controller that has failed `max_failures` times (default once) since the last success is
    dropped until another controller succeeds: its dynamics model keeps predicting a success the world does not
    give, and a failed insertion backs off to the state it started from, where the same open-loop controller would
    fail the same way; without this the selector retries it until the episode runs out. A success that only
    brings the part back to where it failed (a move after a failed insertion) would let it fail again and again,
    so `episode_failures` failures in the episode drop it for good.
    """

    def __init__(self, max_failures: int, episode_failures: int | None = None):
        self.max_failures, self.episode_failures = max_failures, episode_failures
        self.just_done: str | None = None
        self.failures: Counter[str] = Counter()  # since the last success
        self.all_failures: Counter[str] = Counter()  # in the episode

    def record(self, activation: Activation) -> None:
        self.just_done = activation.controller if activation.outcome == "done" else None
        if activation.outcome == "done":
            self.failures.clear()
        elif activation.outcome != "preempted":
            self.failures[activation.controller] += 1
            self.all_failures[activation.controller] += 1

    def allows(self, name: str) -> bool:
        return (name != self.just_done and self.failures[name] < self.max_failures
                and (self.episode_failures is None or self.all_failures[name] < self.episode_failures))


def sensed(library: dict[str, Controller], obs) -> dict:
    """What the library's controllers sensed when the selector decided (their initiation sets' predicates), for the
    decision log: {"sensed": {predicate: probability}, "senses": "learned" or "oracle"} ({} for controllers without
    senses)."""
    senses = next((c.senses for c in library.values() if getattr(c, "senses", None) is not None), None)
    if senses is None:
        return {}
    percept = senses(obs)
    return {"sensed": {k: round(p, 3) for k, p in percept.probabilities.items()}, "senses": percept.source}


FrameHook = Callable[[dict, str, float], None]  # (observation, running controller, goal score now)


def compose_episode(env, library: dict[str, Controller], world: WorldModel, config: ComposeConfig, seed: int,
                    on_frame: FrameHook | None = None) -> ComposedEpisode:
    """One composed episode from `env.reset(seed)`. Only controllers with a dynamics model are candidates."""
    names = [n for n in world.dynamics if n in library]
    if not names:
        raise ValueError(f"none of the library's controllers ({list(library)}) has a dynamics model "
                         f"(the world model has {list(world.dynamics)})")
    selector = world.selector(config.horizon, config.samples, seed=seed, controllers=names)
    u = env.unwrapped
    task = task_of(u)
    obs, info = env.reset(seed=seed)
    result = ComposedEpisode(seed, reached=int(info["stage"][0]))
    running: Controller | None = None
    current: Activation | None = None
    eligibility = Eligibility(config.max_failures, config.episode_failures)

    def choose(step: int) -> Controller | None:
        """Decide and start the chosen controller; one that cannot even start (no plan) fails on the spot."""
        while True:
            applicable = torch.tensor([[library[n].can_start(obs) and eligibility.allows(n) for n in names]])
            if not applicable.any():
                return None
            decision = selector.decide(world.encode(obs), applicable)
            result.decisions.append({"step": step, **decision.log(0), **sensed(library, obs)})
            chosen = library[decision.chosen(0)]
            subtask = getattr(chosen, "subtask", None)
            result.activations.append(Activation(chosen.name, step, subtask=getattr(subtask, "name", "")))
            try:
                chosen.start(obs, seed=seed * 1000 + step)
                return chosen
            except PlanningError as e:
                result.activations[-1].outcome, result.activations[-1].reason = "failed", f"no plan: {e}"
                result.activations[-1].part = task.whereabouts(u, info)
                eligibility.record(result.activations[-1])

    for step in range(config.max_steps):
        due = running is not None and config.reselect_every and current.steps >= config.reselect_every
        if running is None or running.done(obs) or due:
            if current is not None:
                current.outcome = running.outcome.value if running.done(obs) else "preempted"
                current.reason = getattr(running, "reason", "")
                current.part = task.whereabouts(u, info)
                eligibility.record(current)
            running = choose(step)
            if running is None:
                break
            current = result.activations[-1]
        obs, _, _, _, info = env.step(task.env_action(u, running.act(obs)))
        current.steps += 1
        result.steps = step + 1
        result.reached = max(result.reached, task.stage(u, info))
        if on_frame is not None:
            on_frame(obs, running.name, world.score_observation(obs))
    # The scorer's verdict, from the info the last step (or the reset) gave.
    result.success, result.part = bool(info["success"][0]), task.whereabouts(u, info)
    if running is None:
        result.ended = "task done" if result.success else "nothing applicable"
    else:
        result.ended = "out of steps"
        if current.outcome == "running":
            current.outcome = running.outcome.value if running.done(obs) else "cut off at max_steps"
            current.reason = getattr(running, "reason", "")
        current.part = result.part
    result.knocked_out = bool(getattr(u, "knocked_out", False))
    return result
