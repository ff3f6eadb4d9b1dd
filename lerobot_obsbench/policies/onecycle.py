"""The paper's learning-rate schedule, registered with LeRobot as the scheduler type `onecycle`."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.optim.schedulers import LRSchedulerConfig
from torch.optim import Optimizer
from torch.optim.lr_scheduler import LRScheduler, OneCycleLR


@LRSchedulerConfig.register_subclass("onecycle")
@dataclass
class OneCycleSchedulerConfig(LRSchedulerConfig):
    """torch's OneCycleLR over the whole run (the paper's schedule, stepped per batch); peak = each parameter
    group's lr."""

    num_warmup_steps: int | None = None
    pct_start: float = 0.15
    anneal_strategy: str = "cos"
    div_factor: float = 100.0
    final_div_factor: float = 1000.0

    def build(self, optimizer: Optimizer, num_training_steps: int) -> LRScheduler:
        return OneCycleLR(
            optimizer,
            max_lr=[g["lr"] for g in optimizer.param_groups],
            total_steps=max(num_training_steps, 2),
            pct_start=self.pct_start,
            anneal_strategy=self.anneal_strategy,
            div_factor=self.div_factor,
            final_div_factor=self.final_div_factor,
        )
