"""A toy env and policy for the lockstep evaluation loop's tests (`envs.evaluate`, `envs.vector`): episodes whose
length and outcome depend on their seed, and a policy whose actions carry what it was shown, so that a slot mixed
up with another, stepped after its end or fed another episode's observation shows in the results."""

from __future__ import annotations

import os

import numpy as np
import torch


class ToyEnv:
    """Episode of seed s: a success at step s % 4 + 2 if every action named the seed, else it runs on. Reward of a
    step: the action's second value (the step the policy saw). Seed 13 cannot be reset (a worker's error)."""

    def __init__(self, tag: str = "toy", device: str | None = None):
        self.tag, self.device, self.seed, self.t, self.done = tag, device, None, 0, True

    def process(self) -> tuple[int, int]:
        """The process holding this env, and its parent: which start method made a worker shows there."""
        return os.getpid(), os.getppid()

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


def make_toy_env(tag: str = "toy", device: str | None = None) -> ToyEnv:
    return ToyEnv(tag, device)


class EchoPolicy:
    """Acts with what it sees, (seed, step), and records each call's batch size."""

    def __init__(self):
        self.batch_sizes, self.resets = [], 0

    def reset(self) -> None:
        self.resets += 1

    def select_action(self, batch: dict) -> torch.Tensor:
        self.batch_sizes.append(len(batch["observation.state"]))
        return batch["observation.state"].clone()


class ToyBatchEnv:
    """`num_envs` toy episodes simulated together, the way ManiSkill's GPU simulation steps them: every env steps
    on every call (an env whose episode ended stands still), and observations are torch tensors."""

    device = "cpu"

    def __init__(self, num_envs: int, tag: str = "toy"):
        self.num_envs, self.envs = num_envs, [ToyEnv(f"{tag}[{i}]") for i in range(num_envs)]
        self.seeds_seen: list[list[int]] = []

    def _batch(self, observations: list[dict]) -> dict:
        return {"agent_pos": torch.as_tensor(np.stack([o["agent_pos"] for o in observations]))}

    def reset_all(self, seeds):
        self.seeds_seen.append(list(seeds))
        results = [env.reset(seed) for env, seed in zip(self.envs, seeds, strict=True)]
        return self._batch([obs for obs, _ in results]), {"is_success": torch.zeros(self.num_envs, dtype=torch.bool)}

    def step_all(self, actions: torch.Tensor):
        assert actions.shape[0] == self.num_envs, actions.shape
        results = [
            env.step(action.numpy()) if not env.done else (env._obs(), 0.0, False, False, {"is_success": True})
            for env, action in zip(self.envs, actions, strict=True)
        ]
        info = {
            key: torch.tensor([r[4].get(key, True) for r in results]) for key in ("is_success", "sub_success/named")
        }
        return (
            self._batch([r[0] for r in results]),
            torch.tensor([r[1] for r in results]),
            torch.zeros(self.num_envs, dtype=torch.bool),
            torch.zeros(self.num_envs, dtype=torch.bool),
            info,
        )

    def render_all(self) -> torch.Tensor:
        return torch.as_tensor(np.stack([env.render() for env in self.envs]))

    def close(self) -> None:
        pass


def make_toy_batch_env(num_envs: int, tag: str = "toy") -> ToyBatchEnv:
    return ToyBatchEnv(num_envs, tag)
