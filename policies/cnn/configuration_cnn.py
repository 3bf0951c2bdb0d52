"""Configuration of the CNN + mixture density policy (defaults: the paper's training settings)."""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.learning.config import BACKBONES, TrainingConfig, option
from policy_composer.policies.registry import register_kind
from policy_composer.tasks.registry import get_spec, get_task

# What the policy reads of observation.state besides its image, and its size:
# "gripper": the gripper's width only. With the joints as input, a few dozen demonstrations can be fitted from
#            the joints alone (each episode's joint path is unique), and the image gets ignored; measured on
#            the insertion table, see docs/controllers.md.
# "arm": the driven arm's 7 joints and the gripper width (the paper's wording).
# "scene": the gripper width and what the task's kinematics add: where the hand is against the scene the robot knows
#          (on the peg, the hand in the hole's frame: what the hand camera cannot see of a hole in the box's side).
# "auto": "scene" where the task's scene differs between episodes (its spec's scene_names), "gripper" elsewhere.
PROPRIOCEPTION = {"gripper": slice(7, 8), "arm": slice(0, 8), "scene": slice(7, 8)}
# What the mixture density head predicts, and its size (the gripper command is the last entry of both):
# "hand": the next TCP target as a displacement in the hand's own frame (the forearm camera's frame too, so
#         what the image shows maps to the action without the arm's Jacobian); the controller turns it into
#         joint targets by inverse kinematics, keeping the hand's orientation.
# "joint": the next joint targets as deltas from the measured joints (the paper's wording).
ACTION_SPACES = {"hand": 4, "joint": 8}


# The subtasks a CNN policy may be trained for, where its task has them and names the recipe of their
# demonstrations (the task spec's `demonstrations`, and of their DAgger corrections, `corrections`).
SUBTASKS = ("pick", "move", "insert")


@register_kind("cnn", label="CNN", subtasks=SUBTASKS, trained=True, demonstrated=True)
@dataclass
class CNNPolicyConfig(TrainingConfig):
    subtask: str = option("insert", "the subtask the policy is trained for", SUBTASKS)
    camera: str = option("", "the camera the policy sees (default: the task's policy camera)", camera=True)
    view: str = option("auto", "what the policy sees of its camera: the whole image, or the window where the held "
                       "part meets its counterpart (the task's insertion windows); auto: the window for the insertion "
                       "where the camera has one", ("auto", "whole", "insertion"))
    image_size: int = option(64, "images are resized to this square before the encoder", minimum=16)
    backbone: str = option("spatial", "image encoder (see learning.layers.image_encoder)", BACKBONES)
    proprioception: str = option("auto", "what the policy reads besides its image: the gripper width, the arm's "
                                 "joints too, or where the hand is against the scene the robot knows; auto: the "
                                 "scene where it differs between episodes, else the gripper", (*PROPRIOCEPTION, "auto"))
    action_space: str = option("hand", "hand: next TCP displacement in the hand frame (IK to joint targets); "
                               "joint: joint-target deltas", tuple(ACTION_SPACES))
    hidden_dim: int = 256
    num_mixtures: int = option(24, "Gaussian mixture components (paper: 24)", minimum=1)
    # Smallest standard deviation of a component, in units of the target's spread. Without a floor the
    # likelihood is won by shrinking variances, and the means (the actions) are left barely fitted: on two
    # demonstrations, a floor of 0.2 cut the fitted descent error from 2.4 mm to 0.5 mm a step.
    min_std: float = 0.2
    weight_decay: float = 1e-6  # paper
    batch_size: int = option(120, "minibatch size (paper: 120)", minimum=1)
    epochs: int = option(200, "training epochs (paper: 200)", minimum=1)
    # Behaviour cloning's usual guard against memorising a few demonstrations.
    shift: int = option(4, "random-shift augmentation in pixels at image_size (0: none)", minimum=0)
    precision: str = option("float32", "the encoder's convolutions while training: float32, or bfloat16 (about "
                            "twice as fast on a CPU with AMX, slower on one without; the policy acts in float32)",
                            ("float32", "bfloat16"))
    max_steps: int = option(120, "control steps the controller runs before it gives up", minimum=1)
    # An auxiliary loss that makes the encoder see what the insertion turns on: besides the actions, the image
    # features regress the gear's offset from the peg (the recordings' gear_offset label, never an input). Behaviour
    # cloning alone left an encoder that could not tell a centred gear from one 5 mm off (docs/experiments).
    offset_weight: float | None = option(None, "weight of the gear-offset loss (default: 1 for the insertion, "
                                         "0 otherwise)", minimum=0.0)

    def __post_init__(self):
        super().__post_init__()
        spec = get_spec(self.task)
        self.camera = self.camera or spec.policy_camera
        if self.proprioception == "auto":
            self.proprioception = "scene" if spec.scene_names else "gripper"
        if self.camera not in spec.cameras:
            raise ValueError(f"CNNPolicyConfig.camera must be one of {spec.env_id}'s {', '.join(spec.cameras)}, not "
                             f"{self.camera!r}")
        windows = spec.insertion_windows
        if self.view == "auto":
            self.view = "insertion" if self.subtask == "insert" and self.camera in windows else "whole"
        if self.offset_weight is None:
            self.offset_weight = 1.0 if self.subtask == "insert" else 0.0
        if self.view == "insertion" and self.camera not in windows:
            raise ValueError(f"CNNPolicyConfig.view 'insertion' has a window for {', '.join(windows) or 'no camera'} "
                             f"of {spec.env_id} only, not the {self.camera} camera; choose view 'whole'"
                             + (" or one of those cameras" if windows else ""))

    @property
    def window(self) -> tuple[float, float, float] | None:
        """The part of the camera image the policy sees (see to_model_image); None: all of it."""
        return get_spec(self.task).insertion_windows[self.camera] if self.view == "insertion" else None

    @property
    def state_dim(self) -> int:
        sl = PROPRIOCEPTION[self.proprioception]
        extra = len(get_task(self.task).extra_proprioception) if self.proprioception == "scene" else 0
        return sl.stop - sl.start + extra

    @property
    def action_dim(self) -> int:
        return ACTION_SPACES[self.action_space]

    @property
    def binary_actions(self) -> tuple[int, ...]:
        """The gripper command, last in both action spaces (see CNNPolicy)."""
        return (self.action_dim - 1,)
