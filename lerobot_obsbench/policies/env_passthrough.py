"""Lets stock `lerobot-eval` drive the plugin's policies: the env's sensor passthrough is unpacked, and a policy
that does not fit the env is refused with the same message `obsbench eval` gives."""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_obsbench.schema import (
    STATE_KEY,
    cameras_in,
    check_compatibility,
    depth_key,
    frame_to_env_observation,
    image_key,
    unpack_passthrough,
)


def frame_to_policy_batch(frame: dict) -> dict:
    """A schema frame (one robot or simulator step) as the policy's preprocessor takes it in evaluation: the
    env-style observation (sensors in the passthrough) of a batch of one, through LeRobot's
    `preprocess_observation`. Real-robot rollouts and RLBench evaluation feed their frames through it."""
    import numpy as np
    from lerobot.envs.utils import preprocess_observation

    def batched(value):
        return {k: batched(v) for k, v in value.items()} if isinstance(value, dict) else np.expand_dims(value, 0)

    return preprocess_observation(batched(frame_to_env_observation(frame)))


def observed_resolution(batch: dict, cameras: list[str]) -> tuple[int, int] | None:
    """(height, width) of the first of `cameras` found in an unpacked env batch (colour, else depth)."""
    for cam in cameras:
        if image_key(cam) in batch:
            return tuple(batch[image_key(cam)].shape[-2:])
        if depth_key(cam) in batch:
            return tuple(batch[depth_key(cam)].shape[1:3])
    return None


class EnvObservationMixin:
    """Unpacks the env's `observation.robot_state` passthrough (depth, intrinsics, cam2world; see
    `schema.unpack_passthrough`) onto the policy's device before LeRobot's own `select_action` /
    `predict_action_chunk` run, after checking that the env's cameras, resolution and state fit the policy, then
    registers LeRobot-recorded depth with the policy's `calibrated_depth`; `from_pretrained` refuses an env whose
    action size differs from the checkpoint's."""

    def _unpack(self, batch: dict) -> dict:
        unpacked = unpack_passthrough(batch)
        if unpacked is batch:
            return batch
        state = unpacked.get(STATE_KEY)
        check_compatibility(
            self.config,
            cameras=cameras_in(unpacked),
            resolution=observed_resolution(unpacked, list(self.config.cameras)),
            state_dim=state.shape[-1] if isinstance(state, Tensor) else None,
        )
        device = torch.device(self.config.device) if self.config.device else None
        return {k: v.to(device) if isinstance(v, Tensor) and device else v for k, v in unpacked.items()}

    def select_action(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().select_action(self.calibrated_depth(self._unpack(batch)), *args, **kwargs)

    def predict_action_chunk(self, batch: dict, *args, **kwargs) -> Tensor:
        return super().predict_action_chunk(self.calibrated_depth(self._unpack(batch)), *args, **kwargs)

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, config=None, **kwargs):
        # lerobot-eval replaces the config's output features with the env's before loading: compare with the
        # checkpoint's own, so a controller mismatch reads as one, not as a tensor-size error in load_state_dict.
        if config is not None and config.action_feature is not None:
            from lerobot.configs.policies import PreTrainedConfig

            saved = PreTrainedConfig.from_pretrained(pretrained_name_or_path, **_hub_kwargs(kwargs))
            if saved.action_feature is not None and saved.action_feature.shape != config.action_feature.shape:
                check_compatibility(saved, action_dim=config.action_feature.shape[0])
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)


def _hub_kwargs(kwargs: dict) -> dict:
    names = ("force_download", "resume_download", "proxies", "token", "cache_dir", "local_files_only", "revision")
    return {k: kwargs[k] for k in names if k in kwargs}
