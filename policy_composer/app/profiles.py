"""The main job's profiles: how big each stage is. `quick` runs on a 2-core CPU in well under an hour, `paper` uses
the paper's sizes, `smoke` is the smallest that runs every stage (for tests: its figures mean nothing). Light: the
command line offers them as choices."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.selector.configuration import ComposeConfig
from policy_composer.tasks.registry import DEFAULT_TASK


@dataclass(frozen=True)
class Profile:
    name: str
    resolution: int  # recorded camera images, pixels square
    image_size: int  # what the models see
    insertion_demos: int  # paper: 50
    transport_demos: int  # pick-up and carry, for the CNN pick-up and move policies
    full_task_demos: int  # training plus held-out
    train_demos: int  # paper: 5
    dmp_episodes: int  # planner episodes the DMPs are fitted to
    rollouts: int  # per controller, for its dynamics model
    cnn_epochs: int  # paper: 200
    dagger_episodes: int  # a CNN policy's own rollouts labelled by the expert (DAgger), which it trains on again
    dagger_epochs: int  # that training, on the demonstrations and the labelled rollouts together
    dagger_rounds: int  # each records the last policies' rollouts and trains them again (0: none)
    vae_epochs: int
    dynamics_epochs: int
    goal_epochs: int
    predicate_epochs: int  # each predicate classifier's
    table_trials: int  # per Table I cell (paper: 10)
    compose_episodes: int  # the first 10 are Table I's composed row; all of them the success rate over seeds
    knockout_episodes: int
    mdp_episodes_19: int
    mdp_episodes_100: int  # per heatmap cell
    mdp_levels: tuple[float, ...] | None = None  # noise levels of the heatmap (None: the full grid, 0 to 0.8)
    mixtures: int = 24  # paper: 24
    horizon: int = 10  # paper: n = 10
    samples: int = 16
    cnn_max_steps: int = CNNPolicyConfig.max_steps  # a CNN controller's step limit
    compose_max_steps: int = ComposeConfig.max_steps  # control steps of a composed episode
    dagger_subtasks: tuple[str, ...] = ("insert",)  # the CNN policies the DAgger rounds train (SPEC.corrections)
    bfloat16_subtasks: tuple[str, ...] = ()  # the CNN policies whose convolutions train in bfloat16 (--precision)
    insert_trials: int | None = None  # Table I's insert column, where the paper's comparison lies (None: table_trials)
    insert_epochs: int | None = None  # the CNN insertion's behaviour cloning, if not cnn_epochs
    # By task: which results this size supports, and figures at this size that other runs measured (the report links
    # to them in the README). A task with none gets the report's words on its own seeds.
    holds: Mapping[str, str] = field(default_factory=dict)
    elsewhere: Mapping[str, str] = field(default_factory=dict)

    def cnn_training(self, subtasks: tuple[str, ...] = ("pick", "move", "insert")) -> str:
        """The behaviour cloning of the CNN policies of `subtasks` (the task's), as the job's messages and its report
        state it."""
        others = [s for s in subtasks if s != "insert"]
        epochs = (f"{self.cnn_epochs} epochs, the insertion {self.insert_epochs}" if others else
                  f"{self.insert_epochs} epochs") if self.insert_epochs else f"{self.cnn_epochs} epochs"
        bfloat16 = [s for s in self.bfloat16_subtasks if s in subtasks]
        return epochs + (f", in bfloat16 for the {', '.join(bfloat16)}" if bfloat16 else "")


PROFILES = {
    "quick": Profile("quick", resolution=128, image_size=64, insertion_demos=50, transport_demos=20,
                     full_task_demos=7, train_demos=5, dmp_episodes=5, rollouts=4, cnn_epochs=80, insert_epochs=200,
                     dagger_episodes=50, dagger_epochs=120, dagger_rounds=2,
                     bfloat16_subtasks=("pick", "move", "insert"), vae_epochs=15, dynamics_epochs=30,
                     goal_epochs=30, predicate_epochs=6, table_trials=3, insert_trials=10, compose_episodes=10,
                     knockout_episodes=3,
                     mdp_episodes_19=1000, mdp_episodes_100=30,
                     holds={DEFAULT_TASK: (
                         "The MDP experiments, the MP row of Table I, the CNN insertion and the goal-score "
                         "comparison between cameras hold at this size (the MP row needs no training; the CNN "
                         "insertion is the paper profile's recipe up to its second DAgger round, which seated "
                         "96/100 held-out seeds in one run; every insertion of Table I has 10 trials; the MDP runs "
                         "1000 episodes, and 30 in each of the 9x9 noise cells). The CNN pick-up and move (20 "
                         "demonstrations each, 80 epochs) are far below the paper's sizes and their cells have 3 "
                         "trials, so they show that the pipeline works, not how well: run `--profile paper` for "
                         "that. The composed rows' 10 seeds show the selector at work; their rates at this size "
                         "need more seeds than this job runs.")},
                     elsewhere={DEFAULT_TASK: (
                         "the composed row on 100 held-out seeds with the models of an earlier run of this "
                         "profile (measured 2026-12-05), and recovery from 20 knock-outs with those of its "
                         "earlier size (64 px cameras, measured 2026-12-02)")}),
    "paper": Profile("paper", resolution=128, image_size=64, insertion_demos=50, transport_demos=50,
                     full_task_demos=8, train_demos=5, dmp_episodes=5, rollouts=20, cnn_epochs=200,
                     dagger_episodes=50, dagger_epochs=120, dagger_rounds=3, dagger_subtasks=("move", "insert"),
                     bfloat16_subtasks=("insert",),
                     vae_epochs=30, dynamics_epochs=60, goal_epochs=60, predicate_epochs=6,
                     table_trials=10, compose_episodes=50, knockout_episodes=10, mdp_episodes_19=1000,
                     mdp_episodes_100=100,
                     holds={DEFAULT_TASK: (
                         "The paper's sizes: 50 insertion demonstrations (and 50 of the pick-up and carry), 5 "
                         "full-task demonstrations, 200 epochs, 24 mixtures, n = 10, 10 trials per Table I cell, "
                         "and 50 composed seeds.")}),
    "smoke": Profile("smoke", resolution=32, image_size=32, insertion_demos=1, transport_demos=1,
                     full_task_demos=2, train_demos=1, dmp_episodes=1, rollouts=1, cnn_epochs=2, dagger_episodes=1,
                     dagger_epochs=2, dagger_rounds=1, vae_epochs=2, dynamics_epochs=2, goal_epochs=2,
                     predicate_epochs=1,
                     table_trials=1, insert_trials=2, compose_episodes=1, knockout_episodes=1, mdp_episodes_19=20,
                     mdp_episodes_100=2,
                     mdp_levels=(0.0, 0.4, 0.8), mixtures=4, horizon=3, samples=4, cnn_max_steps=30,
                     compose_max_steps=250, dagger_subtasks=("move", "insert"),
                     holds={DEFAULT_TASK: (
                         "Every stage at the smallest size that runs, to test the pipeline: no figure here means "
                         "anything.")}),
}
