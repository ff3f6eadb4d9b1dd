"""obs_diffusion policy: LeRobot's conditional UNet, noise scheduler and action queues with the plugin's
observation encoder as the conditioning."""

from __future__ import annotations

from collections import deque
from contextlib import contextmanager

import torch
from lerobot.policies.diffusion.modeling_diffusion import (
    DiffusionConditionalUnet1d,
    DiffusionModel,
    DiffusionPolicy,
    DiffusionSinusoidalPosEmb,
    _make_noise_scheduler,
)
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE
from torch import Tensor, nn

from lerobot_obsbench.errors import ConfigError
from lerobot_obsbench.policies.env_passthrough import EnvObservationMixin
from lerobot_obsbench.policies.model_card import ModelCardMixin
from lerobot_obsbench.policies.obs_diffusion.configuration_obs_diffusion import ObsDiffusionConfig
from lerobot_obsbench.policies.observation_encoder import ObservationEncoder
from lerobot_obsbench.spaces import CalibratedDepth


class DiffusionTransformer(nn.Module):
    """Diffusion Policy's time-series transformer denoiser, a drop-in for LeRobot's UNet (same call):
    `(noisy actions (B, T, A), timestep (B,), global_cond (B, n_obs * G)) -> (B, T, A)`.

    Action steps are the decoder's queries (causal self-attention); the memory is one token for the diffusion
    step plus one per observation step, each a linear map of that step's conditioning features.
    """

    def __init__(self, config, cond_dim_per_step: int):
        super().__init__()
        dim, action_dim = config.transformer_dim, config.action_feature.shape[0]
        self.n_obs_steps, self.causal = config.n_obs_steps, config.transformer_causal
        self.action_in = nn.Linear(action_dim, dim)
        self.action_pos = nn.Parameter(torch.zeros(1, config.horizon, dim))
        self.step_embed = nn.Sequential(
            DiffusionSinusoidalPosEmb(dim), nn.Linear(dim, dim * 4), nn.Mish(), nn.Linear(dim * 4, dim)
        )
        self.cond_in = nn.Linear(cond_dim_per_step, dim)
        self.cond_pos = nn.Parameter(torch.zeros(1, 1 + config.n_obs_steps, dim))
        layer = nn.TransformerDecoderLayer(
            dim,
            config.transformer_heads,
            dim_feedforward=4 * dim,
            dropout=config.transformer_attn_dropout,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.decoder = nn.TransformerDecoder(layer, config.transformer_layers)
        self.norm = nn.LayerNorm(dim)
        self.action_out = nn.Linear(dim, action_dim)
        nn.init.normal_(self.action_pos, std=0.02)
        nn.init.normal_(self.cond_pos, std=0.02)

    def forward(self, x: Tensor, timestep: Tensor | int, global_cond: Tensor | None = None) -> Tensor:
        b, horizon = x.shape[:2]
        timestep = torch.as_tensor(timestep, device=x.device).expand(b)
        cond = self.cond_in(global_cond.reshape(b, self.n_obs_steps, -1))
        memory = torch.cat([self.step_embed(timestep)[:, None], cond], dim=1) + self.cond_pos
        queries = self.action_in(x) + self.action_pos[:, :horizon]
        mask = nn.Transformer.generate_square_subsequent_mask(horizon, device=x.device) if self.causal else None
        return self.action_out(self.norm(self.decoder(queries, memory, tgt_mask=mask, tgt_is_causal=self.causal)))


class ObsDiffusionModel(DiffusionModel):
    """DiffusionModel conditioned on [state ‖ observation feature ‖ env state] for each observation step."""

    def __init__(self, config: ObsDiffusionConfig, dataset_stats: dict | None = None):
        # DiffusionModel.__init__ would size the UNet from image features the plugin does not use; build the
        # same parts here with the observation encoder's feature size instead.
        nn.Module.__init__(self)
        self.config = config
        self.observation = ObservationEncoder(
            config, output="global", dim=config.diffusion_step_embed_dim, dataset_stats=dataset_stats
        )
        global_cond_dim = config.robot_state_feature.shape[0] + self.observation.out_dim
        if config.env_state_feature:
            global_cond_dim += config.env_state_feature.shape[0]
        # Stock code calls the denoiser `self.unet`, whichever network it is.
        if config.denoiser == "transformer":
            self.unet = DiffusionTransformer(config, global_cond_dim)
        else:
            self.unet = DiffusionConditionalUnet1d(config, global_cond_dim=global_cond_dim * config.n_obs_steps)
        self.noise_scheduler = _make_noise_scheduler(
            config.noise_scheduler_type,
            num_train_timesteps=config.num_train_timesteps,
            beta_start=config.beta_start,
            beta_end=config.beta_end,
            beta_schedule=config.beta_schedule,
            clip_sample=config.clip_sample,
            clip_sample_range=config.clip_sample_range,
            prediction_type=config.prediction_type,
        )
        self.num_inference_steps = config.num_inference_steps or config.num_train_timesteps
        if config.compile_model:
            self.unet = torch.compile(self.unet, mode=config.compile_mode)

    # One generator per batch row while set (lockstep evaluation): each row's noise is then the stream one episode
    # alone would draw after `torch.manual_seed(its seed)`.
    episode_generators: list[torch.Generator] | None = None

    def conditional_sample(
        self,
        batch_size: int,
        global_cond: Tensor | None = None,
        generator: torch.Generator | None = None,
        noise: Tensor | None = None,
    ) -> Tensor:
        generators = self.episode_generators
        if generators is None or noise is not None:
            return super().conditional_sample(batch_size, global_cond, generator, noise)
        if len(generators) != batch_size:
            raise ConfigError(f"{len(generators)} episode generators for a batch of {batch_size}")
        shape = (1, self.config.horizon, self.config.action_feature.shape[0])
        dtype, device = global_cond.dtype, global_cond.device
        noise = torch.cat([torch.randn(shape, dtype=dtype, device=device, generator=g) for g in generators])
        # the scheduler draws its per-step noise row by row from a list of generators (diffusers' randn_tensor)
        return super().conditional_sample(batch_size, global_cond, generators, noise)

    def _prepare_global_conditioning(self, batch: dict[str, Tensor]) -> Tensor:
        batch_size, n_obs_steps = batch[OBS_STATE].shape[:2]
        # Every observation step is encoded as its own frame.
        frames = {k: batch[k].flatten(0, 1) for k in self.observation.input_keys}
        obs_feature = self.observation(frames).reshape(batch_size, n_obs_steps, self.observation.out_dim)
        feats = [batch[OBS_STATE], obs_feature]
        if self.config.env_state_feature:
            feats.append(batch[OBS_ENV_STATE])
        return torch.cat(feats, dim=-1).flatten(start_dim=1)

    def compute_loss(self, batch: dict[str, Tensor]) -> Tensor:
        # Stock compute_loss only asserts that some visual or env-state input is present; the sensor tensors
        # travel under their own keys, so point that marker at the first of them.
        return super().compute_loss({OBS_IMAGES: batch[self.observation.input_keys[0]], **batch})


class ObsDiffusionPolicy(ModelCardMixin, EnvObservationMixin, DiffusionPolicy):
    """Diffusion policy (queues, inference loop from LeRobot) over any observation space."""

    config_class = ObsDiffusionConfig
    name = "obs_diffusion"

    def __init__(self, config: ObsDiffusionConfig, **kwargs):
        PreTrainedPolicy.__init__(self, config)
        config.read_dataset_meta(kwargs.get("dataset_meta"))
        config.validate_features()
        self.config = config
        self.calibrated_depth = CalibratedDepth(config.depth_calibration)
        self._queues = None
        self.diffusion = ObsDiffusionModel(config, dataset_stats=kwargs.get("dataset_stats"))
        self.reset()

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, None]:
        return super().forward(self.calibrated_depth(batch))

    def observation_encoder(self) -> ObservationEncoder:
        return self.diffusion.observation

    def open_loop_error(self, batch: dict[str, Tensor]) -> Tensor:
        """Per sample: the mean absolute error of the `n_action_steps` actions sampled as at inference against the
        demonstrated ones, over their valid steps, in normalised action units (a preprocessed training batch; the
        held-out diagnostic of `bench.diagnostics`)."""
        batch = self.calibrated_depth(batch)
        predicted = self.diffusion.generate_actions(batch)
        start = self.config.n_obs_steps - 1
        target = batch[ACTION][:, start : start + predicted.shape[1]]
        valid = ~batch["action_is_pad"][:, start : start + predicted.shape[1]].unsqueeze(-1)
        error = (predicted - target).abs() * valid
        return error.sum((1, 2)) / (valid.sum((1, 2)) * error.shape[-1]).clamp_min(1)

    @contextmanager
    def episode_generators(self, generators: list[torch.Generator]):
        """Within: batch row i samples its noise from `generators[i]` (lockstep evaluation, `envs.evaluate`)."""
        self.diffusion.episode_generators = list(generators)
        try:
            yield
        finally:
            self.diffusion.episode_generators = None

    def get_optim_params(self) -> list[dict]:
        """AdamW groups; with `optimizer_decay_exempt_1d`, biases and 1-D parameters without weight decay."""
        return self.config.param_groups(self.named_parameters())

    def reset(self):
        super().reset()
        # Stock reset() only queues state, images, env state and action: add the sensor keys, or
        # select_action would drop them.
        for key in self.diffusion.observation.input_keys:
            self._queues[key] = deque(maxlen=self.config.n_obs_steps)
