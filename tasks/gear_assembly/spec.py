"""What GearAssembly-v1 shows and takes, importable without the simulator: its cameras, the names of its state and
action entries (the LeRobot datasets' feature names), and the settings an env is made with. Configs and the command
line read these, and importing ManiSkill and torch would cost them seconds."""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.tasks.base import TaskSpec

ENV_ID = "GearAssembly-v1"
MAX_EPISODE_STEPS = 400
CAMERA_NAMES = ("head", "left_forearm", "right_forearm")
# Where a forearm camera shows the held gear and the peg below it through the insertion: a square window (top, left,
# side) as fractions of the image. The camera rides on the hand, so the window stays on them; a policy that looks
# at it alone sees the millimetres that decide an insertion at twice the pixels of the whole image at the same size.
INSERTION_WINDOWS = {"left_forearm": (0.1875, 0.28125, 0.5)}
ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
# observation.state: both arms' joint angles and gripper widths, in this order.
STATE_NAMES = tuple(
    [f"left_{j}" for j in ARM_JOINTS] + ["left_gripper_width"]
    + [f"right_{j}" for j in ARM_JOINTS] + ["right_gripper_width"]
)
# action (flat form): per arm 7 joint targets (rad) and 1 gripper command in [-1, 1] (ManiSkill's Panda maps
# it linearly to a finger target of -0.01..0.04 m: -1 closes with force, 1 opens).
ACTION_NAMES = tuple(
    [f"left_{j}" for j in ARM_JOINTS] + ["left_gripper"] + [f"right_{j}" for j in ARM_JOINTS] + ["right_gripper"]
)


CONTROL_FREQ = 20  # control steps per second (ManiSkill's default, which GearAssembly-v1 keeps): the datasets' fps

# Where an episode starts (reset option "start"): the gear on the table, or already in the left gripper above the
# peg where the insertion begins.
START_STATES = ("table", "pre_insertion")
# The paper's Table I columns: each subtask from its own start states, then the full task.
SUBTASK_COLUMNS = ("pick", "move", "insert", "full")
# The scripted expert's phases, in order (a recipe records some of them).
EXPERT_PHASES = ("approach", "descend", "close", "lift", "carry", "insert", "release", "retreat", "done")
# The flags of GearAssemblyEnv.evaluate() that say how far the task went, in the order the task reaches them.
GOAL_FLAGS = ("gear_grasped", "gear_lifted", "gear_at_peg", "success")
# The predicates the controllers' initiation sets, terminations and guards are made of. The env computes each from
# the simulator's truth (`GearAssemblyEnv.predicates`: privileged, for the recordings' labels and the oracle); a
# robot has them from classifiers of its cameras and joints trained on those labels (selector/predicates.py).
PREDICATES = {
    "gear_on_table": "the gear is down on the table, in the fingers or not",
    "gear_grasped": "the gear is between the left fingers",
    "gear_lifted": "the gear is grasped and lifted off the table",
    "gear_held_level": "the gear is lifted, upright in the fingers and near their centre (as the carry needs it)",
    "gear_at_peg": "the gear is held above the peg at the pre-insertion pose",
    "gear_on_peg": "the gear is on the peg, part-way down or seated",
    "gear_seated": "the gear is seated on the peg (the task's success)",
    "gear_lying_flat": "the gear lies flat on the table, out of the hand",
    "gear_off_course": "the gear is in the hand and off the peg, tipped in the fingers or led away from the peg",
}

# What the task can be made with: the radial clearance the gear's hole leaves around the peg (below 0.5 mm the
# gear jams, above 6 mm it tips over the peg), and square camera images.
CLEARANCE_MM = (0.5, 6.0)
# How far off the fingers' centre a grasp may hold the gear: past the small gear's tooth tips (19 mm from its axis)
# the fingers close beside it.
GRASP_OFFSET_MM = (0.0, 19.0)
RESOLUTION = (16, 512)


@dataclass(frozen=True)
class EnvSettings:
    """What a recorded dataset's env was made with (kept in the dataset, so a resumed recording matches)."""

    resolution: int = 128  # camera width and height, pixels
    clearance_mm: float = 2.0  # radial clearance between peg and hole
    cameras: tuple[str, ...] = CAMERA_NAMES

    def __post_init__(self):
        object.__setattr__(self, "cameras", tuple(self.cameras))  # a list when read back from JSON


# What a label's command is a step from (see ExpertConfig.from_arm): "command", the expert's own last command; "arm",
# the measured hand, for a labeller of states it does not drive (DAgger).
EXPERT_LABELS = ("command", "arm")


@dataclass(frozen=True)
class ExpertSettings:
    grasp_offset_mm: float = 12.0
    teleop: bool = False
    arrival_error_mm: float = 4.0  # teleop: how much further off its rough carry may leave the gear
    # Pre-insertion starts: the gear is off the peg's axis by up to this (a uniform draw in the disc), whatever the
    # grasp, as after a carry that watched the gear; 0: the hand is off by a rough carry's error and the gear by
    # its grasp offset besides, so where the gear sits in the fingers tells which way the peg is.
    gear_arrival_mm: float = 0.0
    noise_mm: float = 0.0  # DART: the executed TCP target's drifting offset (see ExpertConfig.noise)
    # What a label's command is a step from (see ExpertConfig.from_arm): "command", the expert's own last command;
    # "arm", the measured hand, for a labeller of states it does not drive (DAgger).
    labels: str = "command"

    def __post_init__(self):
        if self.labels not in EXPERT_LABELS:
            raise ValueError(f"[expert] labels must be one of {list(EXPERT_LABELS)}, not {self.labels!r}")
        low, high = GRASP_OFFSET_MM
        if not low <= self.grasp_offset_mm <= high:
            raise ValueError(f"[expert] grasp_offset_mm must be between {low:g} and {high:g} mm, not "
                              f"{self.grasp_offset_mm!r}")
        for name in ("arrival_error_mm", "gear_arrival_mm", "noise_mm"):
            if getattr(self, name) < 0:
                raise ValueError(f"[expert] {name} must be at least 0, not {getattr(self, name)!r}")

    def reset_options(self) -> dict:
        """The env's reset options these settings ask for: how the gear sits in the hand at a pre-insertion start."""
        options = {"grasp_offset_max": self.grasp_offset_mm / 1000.0}
        if self.gear_arrival_mm > 0:
            options["gear_arrival_max"] = self.gear_arrival_mm / 1000.0
        return options

    def config(self):
        """The scripted expert's ExpertConfig for these settings (the simulator loads only when it is asked for)."""
        from policy_composer.tasks.gear_assembly.expert import ExpertConfig  # noqa: PLC0415  (the simulator)

        return ExpertConfig(grasp_offset=self.grasp_offset_mm / 1000.0, teleop=self.teleop,
                            arrival_error=self.arrival_error_mm / 1000.0, noise=self.noise_mm / 1000.0,
                            from_arm=self.labels == "arm")


SPEC = TaskSpec(
    name="gear-assembly",
    env_id=ENV_ID,
    cameras=CAMERA_NAMES,
    state_names=STATE_NAMES,
    action_names=ACTION_NAMES,
    predicates=PREDICATES,
    start_states=START_STATES,
    expert_phases=EXPERT_PHASES,
    goal_flags=GOAL_FLAGS,
    expert_settings=ExpertSettings,
    env_settings=EnvSettings,
    control_freq=CONTROL_FREQ,
    instruction="Insert the gear held by the left gripper onto the peg held by the right arm.",
    card={"scene": "two Panda arms: the left one picks a gear up and puts it onto a peg the right one holds",
          "state_action": "`observation.state`: both arms' 7 joint angles and gripper widths; `action`: both arms' 7 "
                          "joint targets (rad) and gripper commands (-1 closed, 1 open)",
          "stage": "0 pick, 1 move, 2 insert, 3 done", "success": "the gear seated on the peg"},
    policy_camera="left_forearm",
    latent_camera="left_forearm",
    goal_camera="head",
    predicate_cameras=("head", "left_forearm"),
    # The move keeps the carry's last frames at the pre-insertion pose too, so it learns where the carry ends, not
    # only where the pre-insertion pose's tolerance begins.
    demonstrations={"pick": ("gear-transport-demos", (0,)), "move": ("gear-transport-demos", (1, 2)),
                    "insert": ("gear-insertion-demos", None)},
    full_task_demos="gear-full-task-demos",
    fixed_cameras=("head",),
    controller_rollouts="gear-controller-rollouts",
    corrections={"move": "gear-move-dagger", "insert": "gear-insertion-dagger"},
    insertion_windows=INSERTION_WINDOWS,
)
