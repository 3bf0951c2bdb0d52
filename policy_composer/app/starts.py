"""Where a subtask's trials, rollouts and DAgger episodes start: the task's own start state for it (the reset option
"start"), or where its scripted expert, run unobserved from the reset, reaches the phase the subtask begins at (the
task description's `reset_starts` and `expert_starts`). Privileged: the expert reads the scene, which only setting a
trial up may do."""

from __future__ import annotations

from policy_composer.policies.senses import OracleSenses
from policy_composer.tasks.registry import task_of

RETRIES = 5  # a seed whose start falls outside the subtask's initiation set is replaced by seed + 1000 k


def start_state(env, seed: int, subtask: str, max_steps: int = 300):
    """Reset to `seed` and bring the env to where `subtask` starts; returns the observation.

    That state may still fall outside the subtask's initiation set (a part tilted in the grasp, or too far off its
    counterpart); such a seed is replaced by seed + 1000 (up to RETRIES times), so every trial starts where the
    subtask may."""
    task = task_of(env)
    if subtask not in task.reset_starts and subtask not in task.expert_starts:
        return env.reset(seed=seed)[0]
    for k in range(RETRIES):
        if subtask in task.reset_starts:
            obs = env.reset(seed=seed + 1000 * k, options={"start": task.reset_starts[subtask]})[0]
        else:
            obs = _expert_until(env, seed + 1000 * k, task.expert_starts[subtask], max_steps)
        if obs is not None and task.subtasks[subtask].can_start(OracleSenses(env)(obs)):
            return obs
    raise RuntimeError(f"no valid {subtask} start state from seed {seed} (tried {RETRIES})")


def _expert_until(env, seed: int, phase: str, max_steps: int):
    """Run the task's start expert from the reset until it is in `phase` (None if it never is)."""
    task = task_of(env)
    env.reset(seed=seed)
    expert = task.start_expert(env)
    expert.reset(seed)
    return task.observe(env) if expert_until(env, expert, phase, max_steps) else None


def expert_until(env, expert, phase: str, max_steps: int) -> bool:
    """Step the env with `expert`'s commands until the expert is in `phase` (False if it never gets there). Nothing
    renders on the way: the expert reads the scene, not the cameras."""
    task = task_of(env)
    for _ in range(max_steps):
        if expert.phase == phase:
            return True
        task.step_unobserved(env, expert.act())
    return False
