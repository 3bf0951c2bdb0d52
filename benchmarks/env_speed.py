"""Env steps/s of GearAssembly-v1 (state only; the one camera composing renders, the world model's; the three a
recording renders) against ManiSkill's PickCube-v1 with its camera; and a controller's steps (a step and its own
`evaluate`) with the task's grasp check against ManiSkill's `is_grasping`, which reads the contacts at every call.

Run: python benchmarks/env_speed.py [--steps 200]
All figures come from the same process, so ratios hold on a noisy machine.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import mani_skill.envs  # noqa: F401
import torch

import policy_composer.tasks.gear_assembly.env  # noqa: F401  (registers GearAssembly-v1)


def steps_per_second(env, action_fn, steps: int) -> float:
    env.reset(seed=0)
    for _ in range(10):  # warm-up
        env.step(action_fn())
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(action_fn())
    return steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--stock", action="store_true",
                        help="also time two stock (undecimated) Pandas with three cameras")
    args = parser.parse_args()
    torch.set_num_threads(1)

    ref = gym.make("PickCube-v1", obs_mode="rgb", render_backend="cpu")
    zero = torch.zeros(ref.action_space.shape)
    ref_sps = steps_per_second(ref, lambda: zero, args.steps)
    ref.close()
    print(f"reference PickCube-v1, 1 camera 128x128: {ref_sps:.1f} steps/s")

    configs = [("state only", dict(obs_mode="state_dict")),
               ("1 camera 128x128 (composing MP and DMP: the world model's)", dict(obs_mode="rgb",
                                                                               cameras=("left_forearm",))),
               ("3 cameras 128x128 (recording)", dict(obs_mode="rgb"))]
    if args.stock:
        configs.append(("3 cameras 128x128, stock Panda meshes", dict(obs_mode="rgb", robot_uids=("panda", "panda"))))
    for label, kwargs in configs:
        env = gym.make("GearAssembly-v1", **kwargs)
        u = env.unwrapped
        env.reset(seed=0)
        hold = u.flat_to_dict_action(u.hold_action())
        sps = steps_per_second(env, lambda hold=hold: hold, args.steps)
        print(f"GearAssembly-v1, {label}: {sps:.1f} steps/s ({sps / ref_sps:.2f}x PickCube-v1)")
        env.close()

    env = gym.make("GearAssembly-v1", obs_mode="state_dict")
    u = env.unwrapped
    env.reset(seed=0)
    hold = u.flat_to_dict_action(u.hold_action())

    def checked_hold():  # a controller's step: the env's step and the controller's own evaluate
        u.evaluate()
        return hold

    u._left_grasping = lambda: u.left_arm.is_grasping(u.gear)  # the reference, on this instance only
    ref_rate = steps_per_second(env, checked_hold, args.steps)
    del u._left_grasping
    rate = steps_per_second(env, checked_hold, args.steps)
    env.close()
    print(f"a controller's steps (state only, step + evaluate): the task's grasp check {rate:.1f} steps/s, "
          f"ManiSkill's is_grasping {ref_rate:.1f} steps/s ({rate / ref_rate:.2f}x)")


if __name__ == "__main__":
    main()
