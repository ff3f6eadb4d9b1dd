"""obs_act policy: LeRobot's ACT transformer, VAE and heads with the plugin's observation encoder."""

from __future__ import annotations

import einops
import torch
import torch.nn.functional as F
from lerobot.policies.act.modeling_act import ACT, ACTPolicy, ACTTemporalEnsembler
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from torch import Tensor, nn

from lerobot_obsbench.policies.env_passthrough import EnvObservationMixin
from lerobot_obsbench.policies.model_card import ModelCardMixin
from lerobot_obsbench.policies.obs_act.configuration_obs_act import ObsACTConfig
from lerobot_obsbench.policies.observation_encoder import ObservationEncoder
from lerobot_obsbench.spaces import CalibratedDepth

ENCODER_PREFIX = "model.observation.encoder."


class WeightlessAttention(nn.MultiheadAttention):
    """nn.MultiheadAttention that, at inference, does not compute the head-averaged attention weights LeRobot's
    ACT layers ask for and throw away (`[0]`): PyTorch then runs its fused attention kernel instead of
    materialising a tokens x tokens matrix per head, which dominates inference on long point-token sequences
    (docs/performance.md#measured-design-choices). The same outputs (to float rounding) and parameters; training
    keeps the stock path, so training runs are unchanged."""

    def forward(self, *args, **kwargs):
        if not self.training:
            kwargs["need_weights"] = False
        return super().forward(*args, **kwargs)


class ObsACT(ACT):
    """ACT whose camera tokens come from an `ObservationEncoder` (any obs space).

    With the sensor keys pruned from `input_features`, LeRobot's ACT builds no image backbone; this subclass
    adds the observation encoder and rewrites only `forward`'s token assembly, because point tokens carry
    per-sample 3D positions where stock ACT assumes one 2D position grid shared by the batch.
    """

    def __init__(self, config: ObsACTConfig, dataset_stats: dict | None = None):
        super().__init__(config)
        self.observation = ObservationEncoder(
            config, output="tokens", dim=config.dim_model, dataset_stats=dataset_stats
        )
        for module in (*self.encoder.modules(), *self.decoder.modules()):
            if type(module) is nn.MultiheadAttention:
                module.__class__ = WeightlessAttention

    def _latent(self, batch: dict[str, Tensor], batch_size: int, device: torch.device):
        """VAE encoder (training with actions) -> latent sample, or the zero latent at inference."""
        if not (self.config.use_vae and ACTION in batch and self.training):
            return torch.zeros(batch_size, self.config.latent_dim, device=device), None, None
        cls_embed = einops.repeat(self.vae_encoder_cls_embed.weight, "1 d -> b 1 d", b=batch_size)
        inputs = [cls_embed]
        if self.config.robot_state_feature:
            inputs.append(self.vae_encoder_robot_state_input_proj(batch[OBS_STATE]).unsqueeze(1))
        inputs.append(self.vae_encoder_action_input_proj(batch[ACTION]))
        vae_in = torch.cat(inputs, dim=1)
        n_prefix = vae_in.shape[1] - batch[ACTION].shape[1]
        key_padding_mask = torch.cat(
            [torch.zeros(batch_size, n_prefix, dtype=torch.bool, device=device), batch["action_is_pad"]], dim=1
        )
        cls_out = self.vae_encoder(
            vae_in.permute(1, 0, 2),
            pos_embed=self.vae_encoder_pos_enc.clone().detach().permute(1, 0, 2),
            key_padding_mask=key_padding_mask,
        )[0]
        params = self.vae_encoder_latent_output_proj(cls_out)
        mu, log_sigma_x2 = params[:, : self.config.latent_dim], params[:, self.config.latent_dim :]
        return mu + log_sigma_x2.div(2).exp() * torch.randn_like(mu), mu, log_sigma_x2

    def forward(self, batch: dict[str, Tensor]):
        obs_tokens, obs_pos = self.observation(batch)  # (B, S, D), (B|1, S, D)
        batch_size, device = obs_tokens.shape[0], obs_tokens.device
        latent, mu, log_sigma_x2 = self._latent(batch, batch_size, device)

        tokens_1d = [self.encoder_latent_input_proj(latent)]
        if self.config.robot_state_feature:
            tokens_1d.append(self.encoder_robot_state_input_proj(batch[OBS_STATE]))
        if self.config.env_state_feature:
            tokens_1d.append(self.encoder_env_state_input_proj(batch[OBS_ENV_STATE]))
        pos_1d = self.encoder_1d_feature_pos_embed.weight.unsqueeze(1).expand(-1, batch_size, -1)

        encoder_in = torch.cat([torch.stack(tokens_1d), obs_tokens.transpose(0, 1)])
        encoder_pos = torch.cat([pos_1d, obs_pos.expand(batch_size, -1, -1).transpose(0, 1)])
        encoder_out = self.encoder(encoder_in, pos_embed=encoder_pos)
        decoder_in = torch.zeros(
            self.config.chunk_size, batch_size, self.config.dim_model, dtype=encoder_pos.dtype, device=device
        )
        decoder_out = self.decoder(
            decoder_in,
            encoder_out,
            encoder_pos_embed=encoder_pos,
            decoder_pos_embed=self.decoder_pos_embed.weight.unsqueeze(1),
        )
        return self.action_head(decoder_out.transpose(0, 1)), (mu, log_sigma_x2)


class ObsACTPolicy(ModelCardMixin, EnvObservationMixin, ACTPolicy):
    """ACT policy (action queue, temporal ensembling from LeRobot) over any observation space."""

    config_class = ObsACTConfig
    name = "obs_act"

    def __init__(self, config: ObsACTConfig, **kwargs):
        PreTrainedPolicy.__init__(self, config)
        config.read_dataset_meta(kwargs.get("dataset_meta"))
        config.validate_features()
        self.config = config
        self.calibrated_depth = CalibratedDepth(config.depth_calibration)
        self.model = ObsACT(config, dataset_stats=kwargs.get("dataset_stats"))
        if config.temporal_ensemble_coeff is not None:
            self.temporal_ensembler = ACTTemporalEnsembler(config.temporal_ensemble_coeff, config.chunk_size)
        self.reset()

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """ACT's training loss: the action reconstruction error over non-padded steps, + KL weight x KL. "l1" is
        LeRobot 0.6's ACT (L1 averaged over the valid elements); "mse" the official code's (squared error with
        padded steps zeroed, averaged over all elements)."""
        batch = self.calibrated_depth(batch)
        actions_hat, (mu, log_sigma_x2) = self.model(batch)
        valid = ~batch["action_is_pad"].unsqueeze(-1)
        if self.config.action_loss == "l1":
            error = F.l1_loss(batch[ACTION], actions_hat, reduction="none")
            reconstruction = (error * valid).sum() / (valid.sum() * error.shape[-1]).clamp_min(1)
        else:
            reconstruction = (F.mse_loss(batch[ACTION], actions_hat, reduction="none") * valid).mean()
        loss_dict = {f"{self.config.action_loss}_loss": reconstruction.item()}
        loss = reconstruction
        if self.config.use_vae:
            # KL(latent || N(0, I)), summed over the latent dimensions, averaged over the batch
            kld = (-0.5 * (1 + log_sigma_x2 - mu.pow(2) - log_sigma_x2.exp())).sum(-1).mean()
            loss_dict["kld_loss"] = kld.item()
            loss = loss + kld * self.config.kl_weight
        return loss, loss_dict

    def observation_encoder(self) -> ObservationEncoder:
        return self.model.observation

    def open_loop_error(self, batch: dict[str, Tensor]) -> Tensor:
        """Per sample: the mean absolute error of the chunk predicted as at inference (zero latent) against the
        demonstrated chunk, over its valid steps, in normalised action units (a preprocessed training batch; the
        held-out diagnostic of `bench.diagnostics`)."""
        was_training = self.training
        self.eval()
        try:
            batch = self.calibrated_depth(batch)
            actions_hat, _ = self.model(batch)
        finally:
            self.train(was_training)
        valid = ~batch["action_is_pad"].unsqueeze(-1)
        error = (actions_hat - batch[ACTION]).abs() * valid
        return error.sum((1, 2)) / (valid.sum((1, 2)) * error.shape[-1]).clamp_min(1)

    def get_optim_params(self) -> list[dict]:
        """One parameter group, plus one for the encoder when it has its own learning rate
        (`optimizer_lr_backbone`)."""
        return self.config.param_groups(self.named_parameters(), ENCODER_PREFIX, self.config.optimizer_lr_backbone)
