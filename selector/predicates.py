"""The task's predicates as a robot has them: one binary classifier per predicate of the cameras it sees and the
joint state, trained on the labels the recordings keep from the simulator (the task's PREDICATES), judged on
held-out episodes, and used by the library's controllers for their initiation sets, terminations and guards
(`LearnedSenses`). They live in the world model's folder beside the goal scores:

    ROOT/predicates/<predicate>   config.json + model.safetensors + train_log.json (its held-out figures)
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from policy_composer.data.features import image_key
from policy_composer.data.frames import random_shift, to_model_image
from policy_composer.learning.checkpoint import CheckpointError, check_out, finished, load_checkpoint, save_checkpoint
from policy_composer.learning.layers import image_encoder
from policy_composer.learning.trainer import Fit, cosine_decay, train_model
from policy_composer.policies.senses import THRESHOLD, CachedSenses, Percept
from policy_composer.selector.configuration import PredicateConfig
from policy_composer.tasks.base import TaskDescription
from policy_composer.tasks.registry import get_task

TRAIN_HINT = "policy-composer train predicates"
HELD_OUT_EVERY = 5  # every fifth episode of each dataset is held out of the training, for the figures
def proprioception_names(task: TaskDescription) -> tuple[str, ...]:
    """What the classifiers know of the robot besides the cameras: its joint state, and what the task's kinematics
    add (on the gear: where the left hand is over the peg by both arms' forward kinematics; on the peg: where the hand
    is against the hole the planner knows)."""
    return (*task.spec.state_names, *task.extra_proprioception)


def proprioception(state: torch.Tensor, task: TaskDescription, scene: torch.Tensor | None = None) -> torch.Tensor:
    """(N, len(proprioception_names(task))) float32 of joint states (N, S) and, where the task has them, the scenes
    the robot knows (N, len(task.spec.scene_names))."""
    return torch.cat([state.float(), task.kinematics(state, scene)], dim=-1)


class PredicateModel(nn.Module):
    """P(predicate | the cameras' images, proprioception): the images stacked as channels through a small CNN, the
    standardised proprioception through a linear layer, both into a logit."""

    def __init__(self, config: PredicateConfig):
        super().__init__()
        self.config = config
        self.encoder = image_encoder("small", config.hidden_dim, in_channels=3 * len(config.cameras))
        size = len(proprioception_names(get_task(config.task)))
        self.state = nn.Sequential(nn.Linear(size, config.hidden_dim), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(2 * config.hidden_dim, config.hidden_dim), nn.ReLU(),
                                  nn.Linear(config.hidden_dim, 1))
        self.register_buffer("state_mean", torch.zeros(size))
        self.register_buffer("state_std", torch.ones(size))

    def forward(self, images: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Logits (B,) of images (B, 3C, S, S) in [0, 1] and proprioception (B, len(proprioception_names(task)))."""
        features = torch.cat([self.encoder(images), self.state((state - self.state_mean) / self.state_std)], -1)
        return self.head(features)[:, 0]

    @torch.no_grad()
    def probability(self, images: torch.Tensor, state: torch.Tensor, batch: int = 512) -> torch.Tensor:
        """P for uint8 images (B, 3C, S, S) and proprioception (B, len(proprioception_names(task)))."""
        return torch.cat([torch.sigmoid(self(images[i:i + batch].float() / 255.0, state[i:i + batch].float()))
                          for i in range(0, len(images), batch)])


def stacked(frames: dict[str, torch.Tensor], cameras: tuple[str, ...]) -> torch.Tensor:
    """The cameras' uint8 images of each frame as one (N, 3C, S, S) tensor."""
    return torch.cat([frames[image_key(c)] for c in cameras], dim=1)


def held_out(episode_index: torch.Tensor) -> torch.Tensor:
    """(N,) bool: the frames of one dataset's every HELD_OUT_EVERY-th episode (the 5th, 10th, ...), or of its last
    where it has fewer."""
    last = int(episode_index.max())
    if last < HELD_OUT_EVERY - 1:
        return episode_index == last
    return episode_index % HELD_OUT_EVERY == HELD_OUT_EVERY - 1


def train_predicate(images: torch.Tensor, state: torch.Tensor, labels: torch.Tensor, config: PredicateConfig,
                    progress: bool = True) -> tuple[PredicateModel, list[float]]:
    """Fit one predicate's classifier to uint8 images (N, 3C, S, S), proprioception (N, P) and 0/1 labels (N,)."""
    target = labels.float()

    def build(generator: torch.Generator) -> Fit:
        model = PredicateModel(config)
        model.state_mean.copy_(state.float().mean(0))
        model.state_std.copy_(state.float().std(0).clamp_min(1e-3))
        return Fit(model, len(images), lambda idx: F.binary_cross_entropy_with_logits(
            model(random_shift(images[idx].float() / 255.0, config.shift, generator), state[idx].float()),
            target[idx]))

    # Without the decay the held-out misses of one classifier ranged from 0.3% to 6% with the seed alone.
    return train_model(config, build, f"training predicate {config.predicate}", progress=progress,
                       schedule=cosine_decay(config.epochs) if config.lr_decay else None, postfix="bce")


def predicate_metrics(probability: torch.Tensor, labels: torch.Tensor) -> dict:
    """Accuracy, false-positive and false-negative rates of P >= THRESHOLD against 0/1 labels."""
    said, truth = probability >= THRESHOLD, labels.bool()
    negatives, positives = int((~truth).sum()), int(truth.sum())
    return {"frames": len(labels), "positives": positives, "accuracy": float((said == truth).float().mean()),
            "false_positive_rate": float((said & ~truth).sum() / negatives) if negatives else 0.0,
            "false_negative_rate": float((~said & truth).sum() / positives) if positives else 0.0}


def train_predicates(frames: dict[str, torch.Tensor], out: str | Path, config: PredicateConfig | None = None,
                     predicates: tuple[str, ...] | None = None, progress: bool = True,
                     resume: bool = False) -> dict[str, dict]:
    """One classifier per predicate on `frames` (`load_frames` of the labelled recordings, with the config's cameras,
    "observation.state", "predicates", "held_out", the frames of `held_out` episodes, and
    "observation.environment_state" where the task has it), each judged on the held-out
    frames; returns each one's held-out figures and training time."""
    config = config or PredicateConfig()
    task = get_task(config.task)
    names = tuple(task.spec.predicates)
    predicates = names if predicates is None else predicates
    out = Path(out)
    for name in predicates:
        check_out(out / "predicates" / name, PredicateConfig)
    images, labels = stacked(frames, config.cameras), frames["predicates"]
    state = proprioception(frames["observation.state"], task, frames.get("observation.environment_state"))
    test = frames["held_out"]
    if test.all():
        raise ValueError("the predicates need episodes to train on besides the held-out ones; record more episodes")
    results = {}
    for name in predicates:
        column = names.index(name)
        path, predicate_config = out / "predicates" / name, replace(config, predicate=name)
        if resume and (log := finished(path, predicate_config)):
            results[name] = {**log.get("held_out", {}), "seconds": log["seconds"]}
            continue
        t0 = time.perf_counter()
        model, losses = train_predicate(images[~test], state[~test], labels[~test, column], predicate_config,
                                        progress)
        figures = predicate_metrics(model.probability(images[test], state[test]), labels[test, column])
        seconds = round(time.perf_counter() - t0, 1)
        save_checkpoint(model, predicate_config, path, {"frames": int((~test).sum()), "losses": losses,
                                                        "held_out": figures, "seconds": seconds})
        results[name] = {**figures, "seconds": seconds}
    return results


def load_predicate(path: str | Path) -> PredicateModel:
    return load_checkpoint(path, PredicateConfig, PredicateModel, "predicate classifier", TRAIN_HINT)


def load_predicates(root: str | Path, task: TaskDescription) -> dict[str, PredicateModel]:
    """Every predicate's classifier of the task in `root`/predicates, or a CheckpointError naming what is missing."""
    folder = Path(root) / "predicates"
    missing = [n for n in task.spec.predicates if not (folder / n / "config.json").is_file()]
    if missing:
        raise CheckpointError(f"{folder} has no classifier for {', '.join(missing)}: the controllers cannot sense "
                              f"them; train them with `{TRAIN_HINT}` (or compose with --senses oracle)")
    models = {n: load_predicate(folder / n) for n in task.spec.predicates}
    sizes = {m.config.image_size for m in models.values()}
    if len(sizes) > 1:
        raise CheckpointError(f"the predicate classifiers in {folder} read images of different sizes {sorted(sizes)}; "
                              f"train them again together with `{TRAIN_HINT}`")
    return models


class LearnedSenses(CachedSenses):
    """The predicates from the classifiers: each observation's cameras and joint state, as a robot senses them."""

    source = "learned"

    def __init__(self, models: dict[str, PredicateModel]):
        super().__init__()
        self.models = models
        self.task = get_task(next(iter(models.values())).config.task)
        self.cameras = tuple(dict.fromkeys(c for m in models.values() for c in m.config.cameras))
        self.size = next(iter(models.values())).config.image_size

    @torch.no_grad()
    def perceive(self, obs) -> Percept:
        sensors = obs.get("sensor_data", {})
        missing = [c for c in self.cameras if c not in sensors]
        if missing:
            raise ValueError(f"the predicate classifiers read cameras {missing}; make the env with them "
                             f"(and obs_mode='rgb')")
        images = {c: to_model_image(sensors[c]["rgb"][:1].cpu(), self.size) for c in self.cameras}
        scene = obs["extra"].get("scene")
        state = proprioception(obs["extra"]["state"][:1].cpu(), self.task, None if scene is None else scene[:1].cpu())
        p = {name: float(torch.sigmoid(model(torch.cat([images[c] for c in model.config.cameras], 1), state))[0])
             for name, model in self.models.items()}
        if self.task.rule_out is not None:
            p = self.task.rule_out(p, state[0, len(self.task.spec.state_names):].numpy())
        return Percept(p, self.source)
