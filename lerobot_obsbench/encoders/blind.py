"""`blind`: the encoder of the `none` space, the benchmark's blind control (beyond the paper).

It turns the empty observation into no ACT tokens and a zero-size Diffusion Policy feature, so the policy acts
on its proprioception and goal alone, with everything else (heads, training, evaluation) unchanged. A method
that does not beat it with non-overlapping intervals has not shown that it uses what it sees.
"""

from __future__ import annotations

from torch import Tensor, nn

from lerobot_obsbench.encoders.registry import EncoderContext, EncoderOutput, register_encoder
from lerobot_obsbench.schema import available_spaces


class BlindEncoder(nn.Module):
    def __init__(self, output: str, dim: int):
        super().__init__()
        self.output, self.dim = output, dim

    def forward(self, empty: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """empty (B, 0) -> tokens (B, 0, dim) + pos (1, 0, dim), or a (B, 0) feature."""
        if self.output == "global":
            return empty
        tokens = empty.new_zeros(empty.shape[0], 0, self.dim)
        return tokens, tokens[:1]


def describe_blind(obs_space: str, output: str, dim: int, context: EncoderContext, options: dict) -> EncoderOutput:
    return EncoderOutput(0, dim) if output == "tokens" else EncoderOutput(None, 0)


@register_encoder(
    "blind",
    available_spaces(lambda s: s.control == "blind"),
    "no visual input: the blind control of the `none` space",
    describe_blind,
    default_for=available_spaces(lambda s: s.control == "blind"),
)
def build_blind(obs_space: str, output: str, dim: int) -> BlindEncoder:
    return BlindEncoder(output, dim)
