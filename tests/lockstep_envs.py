"""A toy env and policy for the lockstep evaluation loop's tests (`envs.evaluate`, `envs.vector`): episodes whose
length and outcome depend on their seed, and a policy whose actions carry what it was shown, so that a slot mixed
up with another, stepped after its end or fed another episode's observation shows in the results."""

from __future__ import annotations

import numpy as np
import torch


class ToyEnv:
    """Episode of seed s: a success at step s % 4 + 2 if every action named the seed, else it runs on. Reward of a
    step: the action's second value (the step the policy saw). Seed 13 cannot be reset (a worker's error)."""

    def __init__(self, tag: str = "toy"):
        self.tag, self.seed, self.t, self.done = tag, None, 0, True

    def _obs(self) -> dict:
        return {"agent_pos": np.array([self.seed, self.t], dtype=np.float32)}

    def reset(self, seed: int):
        if seed == 13:
            raise ValueError("seed 13 cannot be reset")
        self.seed, self.t, self.done, self.named = seed, 0, False, True
        return self._obs(), {"is_success": False}

    def step(self, action):
        if self.done:
            raise RuntimeError(f"{self.tag}: stepped after its episode ended")
        self.named = self.named and action[0] == self.seed
        self.t += 1
        success = self.named and self.t >= self.seed % 4 + 2
        self.done = success
        return self._obs(), float(action[1]), False, False, {"is_success": success, "sub_success/named": self.named}

    def render(self) -> np.ndarray:
        return np.full((4, 4, 3), self.t, dtype=np.uint8)

    def close(self) -> None:
        pass


def make_toy_env(tag: str = "toy") -> ToyEnv:
    return ToyEnv(tag)


class EchoPolicy:
    """Acts with what it sees, (seed, step), and records each call's batch size."""

    def __init__(self):
        self.batch_sizes, self.resets = [], 0

    def reset(self) -> None:
        self.resets += 1

    def select_action(self, batch: dict) -> torch.Tensor:
        self.batch_sizes.append(len(batch["agent_pos"]))
        return torch.as_tensor(batch["agent_pos"]).clone()
