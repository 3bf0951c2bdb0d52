"""What a task gives the library of controllers, and what the library asks of it, whatever the task.

A task is described by a `TaskDescription`: its env and the arm the controllers drive, its cameras and the names of
its state and action entries, its predicates (what initiation sets, terminations and guards are made of), its
subtasks as waypoints (`Subtask`), the scene as the robot knows it (`Scene`: its own kinematics and what the planner
may know), and the privileged truth kept apart (`truth`: the simulator's predicates, for labels and the oracle). The
controller kinds, the recorder, the world model and the selector read a task through this description only; each
task's own package under `tasks/` fills it in.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:  # the description is read without the simulator, torch or the collision library
    import pinocchio as pin
    import torch

    from policy_composer.tasks.scene import Obstacle

THRESHOLD = 0.5  # a predicate holds where its probability is at least this


def episode_limit(env) -> int:
    """The control steps an episode of `env` may take: its registered step limit (400 where it has none)."""
    return getattr(env.spec, "max_episode_steps", None) or 400


def np0(x: torch.Tensor) -> np.ndarray:
    """Env 0 of a batched tensor, as float64 numpy."""
    return x[0].detach().cpu().numpy().astype(np.float64)


@dataclass(frozen=True)
class Percept:
    """Each predicate's probability at one observation, and where they came from ("learned" or "oracle")."""

    probabilities: dict[str, float]
    source: str

    def __getitem__(self, name: str) -> bool:
        return self.probabilities[name] >= THRESHOLD

    def why(self, *names: str) -> str:
        """The named predicates as the decision log states them: `gear_on_peg=no (learned p=0.12)`."""
        return ", ".join(f"{n}={'yes' if self[n] else 'no'} ({self.source} p={self.probabilities[n]:.2f})"
                         for n in names)


class PlanningError(RuntimeError):
    """No way through a subtask was found: no IK solution, or no collision-free path (or its start or goal is in
    collision)."""


@dataclass
class Waypoint:
    kind: str  # "free": around obstacles; "line": straight TCP line; "hold": stay (the gripper changes)
    q: np.ndarray  # (9,) goal configuration
    gripper: float
    tcp: np.ndarray | None = None  # goal TCP position (lines)
    quat: np.ndarray | None = None
    step: float = 0.004  # TCP travel per control step on a line (m)
    settle: int = 4  # control steps holding the goal afterwards
    probe: bool = False  # a way that contact may block (a part on another's top): the controller feels for it
    # A line-up that must be exact: once settled there, the controller measures the hand (its joints) and shifts the
    # lines after it by the steady error (a held part's weight sags the arm below its targets).
    trim: bool = False


class Scene(Protocol):
    """Where things are as the robot knows them (world frame): its hand from its joints, the rest from what the task
    lets it know. `planner_noise` (m) is the noise on the one privileged input a task's planner may be given."""

    planner_noise: float

    def seed(self, seed: int | None) -> None:
        """Draw the planner input's noise of an activation from `seed`."""

    def tcp(self) -> np.ndarray:
        """The driven arm's TCP position."""

    def finger_dir(self) -> np.ndarray:
        """The level direction the fingers close along when the hand points down."""

    def planning_obstacles(self) -> list[Obstacle]:
        """The scene as the planner knows it."""

    def guard_obstacles(self) -> list[Obstacle]:
        """What no command of a learned controller may put the arm into (not what its task touches)."""

    def hand_quat(self, ik, q9: np.ndarray) -> np.ndarray:
        """The hand's orientation (wxyz) that a learned controller's Cartesian steps keep, from the arm's joints."""

    def held_part(self, widen: float, lengthen: float) -> tuple[float, float, pin.SE3]:
        """The held part, at the nominal grasp, as a cylinder `widen` (m) wider in radius and `lengthen` longer than
        it: (radius, length, its centre's pose in the TCP frame, the cylinder's axis its z)."""


class Subtask:
    """A subtask as waypoints: what a controller must reach, independent of how it moves; an initiation set and a
    success test made of the task's predicates as the controller perceives them (a `Percept`)."""

    name = ""
    initiation = ""
    releases = False  # whether it ends with the part let go (else: held, as the next subtask needs it)
    holds_part = False  # whether the part is in the hand on the way (the planner attaches it)
    # Whether a planned controller stops once the subtask is sensed achieved (CONFIRM_STEPS in a row), not at the
    # end of its plan: where the plan goes on past what the senses ever saw achieved.
    stops_when_sensed = False
    # The control steps such a controller goes on along its plan once it has sensed the subtask achieved: a
    # classifier that sees the goal a little before the sharp bound that defines it would otherwise stop short of it.
    sensed_margin = 0
    # Whether a controller pushing the held part stops when the hand is held back (policies/arm.py): a part pushed on
    # against what blocks it slides or turns in the fingers, and no controller that assumes the grasp can go on.
    stops_when_held_back = False
    # Offsets (m) to assume in turn, each time a probing waypoint is blocked; () draws the pick-up's perception error.
    search: tuple[float, ...] = ()

    def can_start(self, percept: Percept) -> bool:
        raise NotImplementedError

    def waypoints(self, ik, scene: Scene, q_now: np.ndarray, grasp_offset: float,
                  percept: Percept) -> list[Waypoint]:
        """The way through the subtask for a part (to be) held `grasp_offset` along the fingers."""
        raise NotImplementedError

    def retry(self, ik, scene: Scene, q_now: np.ndarray, grasp_offset: float, percept: Percept) -> list[Waypoint]:
        """The way from a blocked probe for the next guess (the same waypoints as the first)."""
        return self.waypoints(ik, scene, q_now, grasp_offset, percept)

    def succeeded(self, percept: Percept) -> tuple[bool, str]:
        raise NotImplementedError

    def release_blocked(self, percept: Percept, scene: Scene) -> str:
        """Why the gripper must not open now ("" if it may)."""
        return ""

    def off_course(self, percept: Percept, finished: bool) -> str:
        """Why a controller of this subtask must stop now and back off with the part, though it would go on
        (`finished`: it has nothing more to do) ("" if it need not)."""
        return ""

    def back_off(self, ik, scene: Scene, q_now: np.ndarray) -> np.ndarray:
        """Joint targets (T, 7), gripper closed, from a blocked release back to where the subtask starts."""
        return np.zeros((0, 7))


@dataclass(frozen=True)
class TaskSpec:
    """What a task shows and takes, and what its recordings and models are called, importable without the simulator:
    the recipes, the models' configurations and the command line read it."""

    name: str  # the command line's name: `--task NAME`
    env_id: str
    cameras: tuple[str, ...]
    state_names: tuple[str, ...]  # observation.state; its first 8 are the driven arm's 7 joints and gripper width
    action_names: tuple[str, ...]  # the flat action; its first 8 are the driven arm's 7 joint targets and gripper
    predicates: Mapping[str, str]  # name -> what it says
    start_states: tuple[str, ...]  # where an episode may start (the reset option "start"), the first the default
    expert_phases: tuple[str, ...]  # the scripted expert's phases, in order (a recipe records some of them)
    goal_flags: tuple[str, ...]  # the env's `evaluate()` flags an episode may be recorded to reach
    expert_settings: type  # the dataclass of a recipe's [expert] table; its `config()` is the expert's config
    env_settings: type  # the dataclass of what a recording's env is made with (`resolution`, `cameras`, ...)
    control_freq: int  # control steps per second: the datasets' fps
    instruction: str  # what the task asks, in words (LeRobot's `task` string)
    card: Mapping[str, str]  # the dataset card's words: "scene", "state_action", "stage", "success"
    # The cameras each learned model sees unless its configuration says otherwise.
    policy_camera: str
    latent_camera: str
    goal_camera: str
    predicate_cameras: tuple[str, ...]
    # The CNN policy of each subtask: the recipe of its demonstrations and the stages it learns from (None: all);
    # and the recipe of its DAgger corrections.
    demonstrations: Mapping[str, tuple[str, tuple[int, ...] | None]]
    # The recipes of the goal scorers' full-task demonstrations and of the dynamics models' controller rollouts.
    full_task_demos: str
    controller_rollouts: str
    corrections: Mapping[str, str] = field(default_factory=dict)
    # The most DAgger rounds the main job runs on this task (None: as many as its profile says).
    dagger_rounds: int | None = None
    episode_steps: int | None = None  # control steps a composed episode may take (None: the main job's profile says)
    policy_steps: int | None = None  # at most this many control steps a learned controller runs (None: the profile's)
    # The main job trains the predicate classifiers this many times its profile's epochs on this task.
    predicate_epoch_factor: int = 1
    fixed_cameras: tuple[str, ...] = ()  # the cameras not on the arm (the paper compares them with those on it)
    insertion_windows: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    # What the robot knows of each episode's scene, as its planner does (observation.environment_state, `extra.scene`
    # of an observation): empty where the scene the controllers know is the same in every episode.
    scene_names: tuple[str, ...] = ()
    # Counts the changes to what the task's recordings hold (its scene, its labels): the main job records them again.
    revision: int = 0


@dataclass(frozen=True)
class TaskDescription:
    """One task as the library reads it (see the module docstring)."""

    spec: TaskSpec
    arm: str  # the env's attribute of the arm the controllers drive (an agent with `.robot` and `.tcp`)
    progress: tuple[str, ...]  # the predicates that say how far the task went, in the order it reaches them
    grasped: str  # the predicate that says the part is in the hand
    subtasks: Mapping[str, Subtask]
    sequence: tuple[str, ...]  # the full task, when nothing goes wrong
    insertions: Mapping[str, Subtask]  # how the planned controllers may serve the last subtask of `sequence`
    scene: Callable[[Any], Scene]  # env -> the scene as the robot knows it
    truth: Callable[[Any], dict[str, torch.Tensor]]  # env -> each predicate, (B,) bool: privileged
    hold_action: Callable[[Any], torch.Tensor]  # env -> the flat action that holds every joint where it is
    env_action: Callable[[Any, torch.Tensor], Any]  # (env, flat action) -> what env.step takes
    whereabouts: Callable[[Any, dict], str]  # (env, its info) -> where the part is, in words (the compositions' log)
    # (obs_mode, env settings, cameras to render or None for the settings') -> the env, one of it
    make_env: Callable[..., Any]
    expert: Callable[[Any, Any], Any]  # (env, the expert's config) -> the scripted expert (privileged)
    observe: Callable[[Any], dict]  # the env (as made) -> its observation of the scene now
    # (env, its evaluate() or None) -> the recordings' privileged labels: the stage reached, the part's offset in the
    # hand (3), each predicate (0 or 1)
    labels: Callable[[Any, dict | None], tuple[int, np.ndarray, np.ndarray]]
    stage: Callable[[Any, dict], int]  # (env, its info) -> how many of the task's stages it has reached
    # The predicate classifiers' proprioception beyond observation.state: its names, and (N, state), (N, scene) or
    # None -> (N, names);
    # and how the kinematics it gives rule predicates out: (probabilities, one frame's extra entries) -> probabilities.
    extra_proprioception: tuple[str, ...] = ()
    proprioception: Callable[[np.ndarray, np.ndarray | None], np.ndarray] | None = None
    rule_out: Callable[[dict[str, float], np.ndarray], dict[str, float]] | None = None
    # Where each subtask's trials and rollouts start: a start state of the env's (subtask -> the reset option
    # "start"), or where the scripted expert, run unobserved from the reset, reaches a phase (subtask -> phase); any
    # other subtask starts at the reset.
    reset_starts: Mapping[str, str] = field(default_factory=dict)
    expert_starts: Mapping[str, str] = field(default_factory=dict)
    start_expert: Callable[[Any], Any] | None = None  # env -> the expert that takes the scene to `expert_starts`
    step_unobserved: Callable[[Any, torch.Tensor], None] | None = None  # (env, flat action): physics, no renders
    # scenes (N, len(spec.scene_names)) -> (N, 3, 3): the turn, in the hand's frame, into the frame in which the part
    # sits in the hand as in a grasp straight down, whatever the grasp planned (None: the hand's own frame). A
    # learned controller's moves "in the hand's frame" are in it, the same move for the same grasp of the part.
    grasp_turn: Callable[[np.ndarray], np.ndarray] | None = None

    def kinematics(self, state: torch.Tensor, scene: torch.Tensor | None = None) -> torch.Tensor:
        """(N, len(extra_proprioception)) float32: what the task's kinematics add to joint states (N, S), given the
        scenes the robot knows (N, len(spec.scene_names)) where the task has them."""
        if self.proprioception is None:
            return state.new_zeros((len(state), 0)).float()
        if self.spec.scene_names and scene is None:
            raise ValueError(f"{self.spec.env_id}'s kinematics need the scene the robot knows "
                             "(observation.environment_state, the observation's extra.scene); record the dataset "
                             "again with it")
        scene = None if scene is None else scene.double().cpu().numpy()
        return state.new_tensor(self.proprioception(state.double().cpu().numpy(), scene)).float()

    def grasp_turns(self, scene: torch.Tensor | None, n: int) -> np.ndarray:
        """(n, 3, 3): `grasp_turn` of n scenes (N, len(spec.scene_names)); the identity where the task has none."""
        if self.grasp_turn is None or scene is None:
            return np.broadcast_to(np.eye(3), (n, 3, 3))
        return self.grasp_turn(scene.double().cpu().numpy())

    def settings(self, resolution: int, **settings):
        """The task's env settings at `resolution`, with those of `settings` the task has (a gear's clearance)."""
        names = {f.name for f in fields(self.spec.env_settings)}
        return self.spec.env_settings(resolution=resolution, **{k: v for k, v in settings.items() if k in names})

    def subtask(self, name: str, insertion: str | None = None) -> Subtask:
        """The subtask `name`, its last one as `insertion` says (a key of `insertions`)."""
        if insertion is not None and name == self.sequence[-1]:
            return self.insertions[insertion]
        return self.subtasks[name]
