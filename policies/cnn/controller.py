"""The CNN policies as controllers of the library (`cnn_pick`, `cnn_move`, `cnn_insert`): camera pixels and the
gripper's width in, joint targets out."""

from __future__ import annotations

import numpy as np
import sapien
from transforms3d.quaternions import quat2mat

from policy_composer.data.frames import to_model_image
from policy_composer.policies.cnn.configuration_cnn import PROPRIOCEPTION, CNNPolicyConfig
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.policies.cnn.train import load_cnn_library as load  # noqa: F401  (the registry's loader)
from policy_composer.policies.cnn.train import policy_state
from policy_composer.policies.registry import LibraryError
from policy_composer.policies.subtasks import LearnedController, check_camera
from policy_composer.tasks.base import Subtask, np0
from policy_composer.tasks.panda import ArmIK
from policy_composer.tasks.registry import task_of

# How far the commanded TCP may run ahead of the measured one (m). The demonstrations' commands lead it by 8 cm at
# most; a policy pushing against the table or the peg would otherwise wind its command up until the arm reaches a
# joint limit (a pick-up trained on 20 demonstrations did, pressing down beside the gear, and was stopped for
# safety).
MAX_LEAD = 0.10


class CNNController(LearnedController):
    """Each step: the policy's most probable action, added to the controller's running command (the policy
    predicts changes of the command) and turned into the arm's joint targets. A policy in the "hand"
    action space moves the commanded TCP in the hand's frame as its grasp holds the part
    (`TaskDescription.grasp_turns`), the hand kept at the orientation its scene says (`Scene.hand_quat`), by IK from
    the measured joints."""

    def __init__(self, env, policy: CNNPolicy, subtask: Subtask | None = None, max_steps: int | None = None):
        subtask = subtask or task_of(env).subtasks[policy.config.subtask]
        super().__init__(env, subtask, f"cnn_{subtask.name}", max_steps or policy.config.max_steps)
        check_camera(self.env, policy.config.camera, "the CNN policy")
        self.policy = policy
        if policy.config.proprioception == "scene":
            self.obs_keys = (f"sensor_data.{policy.config.camera}.rgb", "extra.state", "extra.scene")
        else:
            sl = PROPRIOCEPTION[policy.config.proprioception]
            self.obs_keys = (f"sensor_data.{policy.config.camera}.rgb", f"extra.state[{sl.start}:{sl.stop}]")

    def reset(self, obs, seed=None):
        super().reset(obs, seed)
        self._quat = self.scene.hand_quat(self.ik, np0(self.ik.arm.robot.get_qpos()))
        self._turn = self.task.grasp_turns(obs.get("extra", {}).get("scene"), 1)[0]
        self._command = self.scene.tcp() if self.policy.config.action_space == "hand" else self.arm_qpos(obs)

    def predict(self, obs):
        camera, size = self.policy.config.camera, self.policy.config.image_size
        image = to_model_image(obs["sensor_data"][camera]["rgb"][:1].cpu(), size, self.policy.config.window)
        scene = obs["extra"].get("scene")
        state = policy_state(obs["extra"]["state"][:1].cpu().float(), self.policy.config,
                             None if scene is None else scene[:1].cpu())
        a = self.policy.act(image, state)[0].numpy().astype(np.float64)
        gripper = float(np.clip(a[-1], -1.0, 1.0))
        if self.policy.config.action_space == "joint":
            self._command = self._command + a[:7]
            return self._command.copy(), gripper
        self._command, q = hand_step(self.ik, self._command, self._turn @ a[:3], self._quat)
        return q, gripper


def hand_step(ik: ArmIK, command: np.ndarray, displacement: np.ndarray,
              quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move the commanded TCP position (world) by `displacement` (m, in the hand's frame), orientation `quat`:
    the new command, kept within MAX_LEAD of the measured TCP, and its joint targets (7), solved from the measured
    joints."""
    command = command + quat2mat(np0(ik.arm.tcp.pose.q)) @ displacement
    lead = command - np0(ik.arm.tcp.pose.p)
    distance = float(np.linalg.norm(lead))
    if distance > MAX_LEAD:
        command = command - lead * (1.0 - MAX_LEAD / distance)
    q9, _ = ik.solve(sapien.Pose(command, quat), np0(ik.arm.robot.get_qpos()))
    return command, q9[:7]


def build(env, subtask, policies: dict[str, CNNPolicy], config: CNNPolicyConfig,
          max_grasp_offset: float) -> CNNController:
    """The registry's builder: the policy trained for the subtask as its controller (at the configuration it was
    trained with, saved beside its weights)."""
    if subtask.name not in policies:
        raise LibraryError(f"the CNN model has no policy for {subtask.name} (it has {', '.join(policies)}); train one "
                           f"with `policy-composer train policy --subtask {subtask.name}`")
    return CNNController(env, policies[subtask.name], subtask)


def cameras(policies: dict[str, CNNPolicy]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(p.config.camera for p in policies.values()))
