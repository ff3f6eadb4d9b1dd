"""`oracle`: the encoder of the `state` space, the benchmark's oracle control (beyond the paper).

It reads the simulator's object poses (`observation.privileged_state`, 7 values per object, standardised with the
dataset's statistics by the observation module) instead of a sensor: one ACT token per object, or the poses
themselves as Diffusion Policy's feature. With the same policy, trainer and evaluation as every seeing space, it
marks what perfect perception could give; a seeing space is read between the blind control and it.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_obsbench.encoders.registry import EncoderContext, EncoderError, EncoderOutput, register_encoder
from lerobot_obsbench.schema import POSE_SIZE, available_spaces


def _objects(state_dim: int) -> int:
    if state_dim < POSE_SIZE or state_dim % POSE_SIZE:
        raise EncoderError(
            f"the oracle reads {POSE_SIZE} values (xyz + quaternion wxyz) per object; got a privileged state of "
            f"size {state_dim} (the dataset's observation.privileged_state, recorded by obsbench demos)"
        )
    return state_dim // POSE_SIZE


class OracleEncoder(nn.Module):
    def __init__(self, output: str, dim: int, state_dim: int):
        super().__init__()
        self.output, self.objects = output, _objects(state_dim)
        if output == "tokens":
            self.proj = nn.Linear(POSE_SIZE, dim)
            self.pos = nn.Parameter(torch.randn(1, self.objects, dim) * 0.02)

    def forward(self, poses: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """poses (B, 7 * O) -> tokens (B, O, dim) + pos (1, O, dim), or the (B, 7 * O) feature."""
        if self.output == "global":
            return poses
        return self.proj(poses.unflatten(-1, (self.objects, POSE_SIZE))), self.pos


def describe_oracle(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
    state_dim = options["state_dim"]
    return EncoderOutput(_objects(state_dim), dim) if output == "tokens" else EncoderOutput(None, state_dim)


@register_encoder(
    "oracle",
    available_spaces(lambda s: s.control == "oracle"),
    "the simulator's object poses, one token per object: the oracle control of the `state` space",
    describe_oracle,
    default_for=available_spaces(lambda s: s.control == "oracle"),
)
def build_oracle(obs_space: str, output: str, dim: int, state_dim: int = POSE_SIZE) -> OracleEncoder:
    return OracleEncoder(output, dim, state_dim)
