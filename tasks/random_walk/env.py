"""The random-walk MDP of the paper's first experiment ("Simulated MDP"; Harutyunyan et al. 2018's 19-state walk).

States 1..N are non-terminal; 0 and N+1 are terminal. Actions: 0 = left, 1 = right. Reward +1 only on
reaching N+1. The default start is the middle state, (N+1)//2, as in the classic random walk; the paper's
100-state optimum ("12 activations of policy 1") fits a start near the middle. Its 19-state figure starts
at the far left (its left controller reaches state 0 in one activation), so the 19-state experiment passes
`start=1`.
"""

from __future__ import annotations

import gymnasium as gym
from gymnasium import spaces

LEFT, RIGHT = 0, 1


class RandomWalkEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, num_states: int = 19, start: int | None = None):
        if num_states < 2:
            raise ValueError(f"a random walk needs at least 2 non-terminal states, got num_states={num_states}")
        start = (num_states + 1) // 2 if start is None else start
        if not 1 <= start <= num_states:
            raise ValueError(f"start must be a non-terminal state in 1..{num_states}, got {start}")
        self.num_states = num_states
        self.start = start
        self.goal = num_states + 1
        self.observation_space = spaces.Discrete(num_states + 2)
        self.action_space = spaces.Discrete(2)
        self.state = start

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.state = int((options or {}).get("start", self.start))
        return self.state, {}

    def step(self, action: int):
        if self.terminal(self.state):
            raise RuntimeError("step() called on a finished episode; call reset()")
        self.state += 1 if int(action) == RIGHT else -1
        reward = 1.0 if self.state == self.goal else 0.0
        return self.state, reward, self.terminal(self.state), False, {"success": self.state == self.goal}

    def terminal(self, state: int) -> bool:
        return state <= 0 or state >= self.goal


gym.register("RandomWalk-v0", entry_point=RandomWalkEnv)
