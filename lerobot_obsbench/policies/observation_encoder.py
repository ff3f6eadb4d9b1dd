"""The observation module of both policies: ObservationAdapter (sensors -> the space's inputs) + a registry
encoder (inputs -> ACT tokens or a Diffusion Policy feature)."""

from __future__ import annotations

import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from torch import Tensor, nn

from lerobot_obsbench import geometry
from lerobot_obsbench.encoders import encoder_output, make_encoder
from lerobot_obsbench.errors import UnsupportedError
from lerobot_obsbench.schema import EE_POSE_SIZE, PRIVILEGED_STATE_KEY, STATE_KEY, space_info
from lerobot_obsbench.spaces import ObservationAdapter


class StateDenormalizer(nn.Module):
    """Recovers the raw observation.state from the normalised one (LeRobot normalises before the model).

    Needed for the end-effector frame. Its buffers come from the dataset stats at construction and are saved
    with the checkpoint, so a loaded policy needs no stats.
    """

    def __init__(self, state: PolicyFeature | None, mode: NormalizationMode, stats: dict | None):
        super().__init__()
        dim = state.shape[0] if state is not None else 0
        loc, scale = torch.zeros(dim), torch.ones(dim)
        st = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in (stats or {}).items()}
        if st and mode is NormalizationMode.MEAN_STD:
            loc, scale = st["mean"], st["std"]
        elif st and mode is NormalizationMode.MIN_MAX:
            span = st["max"] - st["min"]
            span = torch.where(span == 0, torch.full_like(span, 1e-8), span)
            loc, scale = st["min"] + span / 2, span / 2
        elif st and mode is not NormalizationMode.IDENTITY:
            raise UnsupportedError(f"state normalisation {mode} is not supported for the ee frame")
        self.register_buffer("loc", loc.reshape(dim))
        self.register_buffer("scale", scale.reshape(dim))

    def forward(self, state: Tensor) -> Tensor:
        return state * self.scale + self.loc


class Standardizer(nn.Module):
    """(x - mean) / std with the dataset's statistics, kept as buffers so a loaded policy needs no stats. The oracle's
    input is standardised here rather than by LeRobot's normaliser, because in evaluation it arrives in the env's
    sensor passthrough, after the preprocessor. A value that barely varies in the demonstrations (a resting height,
    an upright quaternion) is divided by at least `min_std`, not amplified."""

    def __init__(self, dim: int, stats: dict | None, min_std: float = 1e-2):
        super().__init__()
        st = {k: torch.as_tensor(v, dtype=torch.float32).reshape(-1) for k, v in (stats or {}).items()}
        self.register_buffer("mean", st.get("mean", torch.zeros(dim)))
        self.register_buffer("std", st.get("std", torch.ones(dim)).clamp_min(min_std))

    def forward(self, x: Tensor) -> Tensor:
        return (x - self.mean) / self.std


class ObservationEncoder(nn.Module):
    """Sensor batch -> tokens/pos (ACT, `output="tokens"`) or one feature vector (DP, `output="global"`);
    `out_dim` is the token width or the feature size the registry declares for this config."""

    def __init__(self, config, output: str, dim: int, dataset_stats: dict | None = None):
        super().__init__()
        self.adapter = ObservationAdapter(config.adapter_config())
        options = config.encoder_options()
        self.encoder = make_encoder(config.encoder, config.obs_space, output=output, dim=dim, **options)
        self.out_dim = encoder_output(
            config.encoder, config.obs_space, output=output, dim=dim, context=config.encoder_context(), **options
        ).width
        mode = config.normalization_mapping.get(FeatureType.STATE.value, NormalizationMode.IDENTITY)
        stats = (dataset_stats or {}).get(STATE_KEY)
        self.state = StateDenormalizer(config.input_features.get(STATE_KEY), mode, stats)
        self.privileged = None
        if space_info(config.obs_space).control == "oracle":
            stats = (dataset_stats or {}).get(PRIVILEGED_STATE_KEY)
            self.privileged = Standardizer(config.privileged_state_dim, stats)
        # the keys the adapter reads (the blind space reads the state, for the batch size only)
        reads_state = self.adapter.needs_ee_pose or space_info(config.obs_space).control == "blind"
        self.input_keys = config.observation_keys() + ([STATE_KEY] if reads_state else [])
        # the encoder compiled for training (`compile_encoder`): the same parameters, held outside the module tree
        # so that the state dict and checkpoints stay those of the eager encoder
        self._compiled = (torch.compile(self.encoder),) if config.compile_encoder else None

    def forward(self, batch: dict[str, Tensor]) -> Tensor | tuple[Tensor, Tensor]:
        ee_pose = None
        if self.adapter.needs_ee_pose:
            pose = self.state(batch[STATE_KEY])[..., -EE_POSE_SIZE:]
            ee_pose = geometry.pose_to_matrix(pose[..., :3], pose[..., 3:])
        inputs = self.adapter(batch, ee_pose=ee_pose)
        encoder = self._compiled[0] if self._compiled is not None and self.training else self.encoder
        return encoder(inputs if self.privileged is None else self.privileged(inputs))
