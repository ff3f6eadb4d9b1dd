"""Lets stock `lerobot-eval` drive the plugin's policies (DESIGN §10)."""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_obsbench.schema import unpack_passthrough


class EnvObservationMixin:
    """Unpacks the env's `observation.robot_state` passthrough (depth, intrinsics, cam2world; see
    `schema.unpack_passthrough`) onto the policy's device before LeRobot's own `select_action` /
    `predict_action_chunk` run."""

    def _unpack(self, batch: dict) -> dict:
        unpacked = unpack_passthrough(batch)
        if unpacked is batch:
            return batch
        device = torch.device(self.config.device) if self.config.device else None
        return {k: v.to(device) if isinstance(v, Tensor) and device else v for k, v in unpacked.items()}

    def select_action(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().select_action(self._unpack(batch), *args, **kwargs)

    def predict_action_chunk(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().predict_action_chunk(self._unpack(batch), *args, **kwargs)
