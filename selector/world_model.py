"""The selector's learned world of a task: the VAE's latent state, one dynamics model per controller,
and the goal score of decoded latents. Trained from recorded datasets, saved as one folder:

    ROOT/vae/                  the VAE (config.json + model.safetensors)
    ROOT/dynamics/<controller> one latent dynamics model per controller
    ROOT/goal_score/<camera>   one goal scorer per camera; the VAE's camera's scores the selector's decoded predictions
    ROOT/goal_score/latent     the goal scorer of the VAE's latents: scores the predictions without decoding them
    ROOT/predicates/<name>     one classifier per task predicate: what the library's controllers sense
"""

from __future__ import annotations

from pathlib import Path

import torch

from policy_composer.data.frames import to_model_image
from policy_composer.learning.checkpoint import CheckpointError, trained_with, weights_id
from policy_composer.policies.senses import OracleSenses, Senses
from policy_composer.selector.batched import LatentSelector
from policy_composer.selector.configuration import GOAL_SCORES
from policy_composer.selector.dynamics import LatentDynamics, load_dynamics
from policy_composer.selector.goal_score import (
    GoalScoreModel,
    LatentGoalScoreModel,
    load_goal_score,
    load_latent_goal_score,
)
from policy_composer.selector.predicates import LearnedSenses, PredicateModel, load_predicates
from policy_composer.selector.vae import VAE, load_vae
from policy_composer.tasks.registry import get_task


def check_trained_together(vae: Path, made_with: dict[Path, dict[str, str]]) -> None:
    """Refuse dynamics models and goal scores (each part's `trained_with`) trained with another VAE than `vae` (a
    retraining cut short, or folders mixed by hand): their latents or reconstructions would not be this VAE's."""
    vae_id = weights_id(vae)
    again = "train the world model again as one: `policy-composer train world-model`, then `train goal-score`"
    for part, parts in made_with.items():
        if "vae" not in parts:
            raise CheckpointError(f"{part / 'config.json'} does not name the VAE it was trained with (trained before "
                                  f"the check, without a VAE, or edited), so it cannot be shown to belong to {vae}; "
                                  f"{again}")
        if parts["vae"] != vae_id:
            raise CheckpointError(f"{part} was trained with another VAE than the one in {vae}; {again}")


class WorldModel:
    """Implements the selector's GoalScore on latents, and turns observations into latents."""

    def __init__(self, vae: VAE, dynamics: dict[str, LatentDynamics], goal: GoalScoreModel | LatentGoalScoreModel,
                 controller_models: dict[str, str] | None = None, predicates: dict[str, PredicateModel] | None = None):
        camera = vae.config.camera
        self.latent_goal = isinstance(goal, LatentGoalScoreModel)
        if self.latent_goal and goal.config.latent_dim != vae.config.latent_dim:
            raise CheckpointError(f"the latent goal score reads {goal.config.latent_dim}-D latents, but the VAE's are "
                                  f"{vae.config.latent_dim}-D; train it with this VAE (`policy-composer train "
                                  f"goal-score`)")
        if not self.latent_goal and goal.config.camera != camera:
            raise CheckpointError(f"the selector's goal score must read the VAE's camera ({camera!r}) to score decoded "
                                  f"predictions; got a goal score for {goal.config.camera!r}")
        skips = {m.config.frame_skip for m in dynamics.values()}
        if len(skips) > 1:
            raise CheckpointError(f"the dynamics models step different numbers of control steps ({sorted(skips)}); "
                                  f"the selector compares them over one horizon, so train them with one frame_skip")
        self.vae, self.dynamics, self.goal = vae, dynamics, goal
        self.decoder = vae.inference_decoder()
        self.camera = camera
        self.controller_models = controller_models or {}  # the model each dynamics model's rollouts ran, by id
        self.predicates = predicates or {}
        self.frame_skip = skips.pop() if skips else 1

    @classmethod
    def load(cls, root: str | Path, controllers: list[str] | None = None, goal_score: str = "image",
             predicates: bool = False) -> WorldModel:
        """Load the VAE, its goal score (`goal_score` "image": the one of its camera; "latent": the one of its
        latents), the dynamics models of `controllers` (default: all) and, with `predicates`, the predicate
        classifiers."""
        if goal_score not in GOAL_SCORES:
            raise ValueError(f"goal_score must be one of {', '.join(GOAL_SCORES)}, not {goal_score!r}")
        root = Path(root)
        vae = load_vae(root / "vae")
        folder = root / "dynamics"
        available = sorted(p.name for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []
        names = controllers if controllers is not None else available
        missing = [n for n in names if n not in available]
        if missing or not names:
            raise CheckpointError(f"{root} has no dynamics model for {missing or 'any controller'} "
                                  f"(it has {available}); "
                                  f"record their rollouts and train them with `policy-composer train world-model`")
        goal = root / "goal_score" / (vae.config.camera if goal_score == "image" else "latent")
        made_with = {folder / n: trained_with(folder / n, "dynamics model", "policy-composer train world-model")
                     for n in names}
        if (goal / "config.json").is_file():  # missing: load_goal_score says how to train it
            made_with[goal] = trained_with(goal, "goal score", "policy-composer train goal-score")
        check_trained_together(root / "vae", made_with)
        dynamics = {n: load_dynamics(folder / n, vae.config.latent_dim) for n in names}
        models = {n: made_with[folder / n].get("controller") for n in names}
        goal_model = load_goal_score(goal) if goal_score == "image" else load_latent_goal_score(goal)
        return cls(vae, dynamics, goal_model, {n: m for n, m in models.items() if m},
                   load_predicates(root, get_task(vae.config.task)) if predicates else None)

    def senses(self, env, source: str) -> Senses:
        """What the library's controllers perceive the predicates with: "learned" (this world model's classifiers) or
        "oracle" (the simulator's truth)."""
        if source == "oracle":
            return OracleSenses(env)
        if not self.predicates:
            raise CheckpointError("this world model was loaded without its predicate classifiers; load it with "
                                  "predicates=True (or compose with --senses oracle)")
        return LearnedSenses(self.predicates)

    def cameras(self, source: str) -> tuple[str, ...]:
        """The cameras the selector and, with learned senses, the predicate classifiers read."""
        learned = source == "learned"
        return tuple(dict.fromkeys((self.camera, *(c for m in self.predicates.values() for c in m.config.cameras
                                                   if learned))))

    def check_controllers(self, models: dict[str, str]) -> None:
        """Refuse controllers (their models by `weights_id`, see `library.model_ids`) other than those whose rollouts
        trained the dynamics models: the predictions would be of another policy."""
        for name in self.dynamics:
            made_with, given = self.controller_models.get(name), models.get(name)
            if made_with != given:
                raise CheckpointError(
                    f"the {name} dynamics model was trained on rollouts of another model than the {name} given "
                    f"(made with {made_with or 'no model'}, given {given or 'no model'}); give "
                    f"the model (or --insertion) it was trained on, or record {name}'s rollouts with this one and "
                    f"train the world model again")

    @torch.no_grad()
    def encode(self, obs) -> torch.Tensor:
        """The latent state of env 0's observation, (1, L)."""
        if self.camera not in obs.get("sensor_data", {}):
            raise ValueError(f"the world model reads camera {self.camera!r}; make the env with it (and obs_mode='rgb')")
        image = to_model_image(obs["sensor_data"][self.camera]["rgb"][:1].cpu(), self.vae.config.image_size)
        return self.vae.encode(image)[0]

    @torch.no_grad()
    def score(self, states: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """G of latent states, (M, L) -> (M,): of the latents, or of their decoded images."""
        return self.goal.expected(states if self.latent_goal else self.decoder(states))

    @torch.no_grad()
    def score_observation(self, obs) -> float:
        """G of what the camera sees now (no decoding): for curves and videos."""
        if self.latent_goal:
            return float(self.goal.expected(self.encode(obs))[0])
        image = obs["sensor_data"][self.camera]["rgb"][:1].cpu()
        return float(self.goal.expected(to_model_image(image, self.goal.config.image_size))[0])

    def selector(self, horizon: int = 10, samples: int = 16, seed: int | None = None, controllers=None,
                 keep_predictions: bool = False, batched: bool = True) -> LatentSelector:
        """A selector over `controllers` (default: every one with a dynamics model)."""
        dynamics = {n: self.dynamics[n] for n in (controllers or self.dynamics)}
        return LatentSelector(dynamics, self, horizon, samples, seed, keep_predictions, batched)
