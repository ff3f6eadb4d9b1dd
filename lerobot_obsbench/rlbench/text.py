"""Language goals: a text encoder turns a variation description into `observation.environment_state`.

The paper's code encodes `descriptions[0]` with OpenAI CLIP ViT-B/16 (`encode_text`: the end-of-text token's
feature projected to 512-d, not normalised). `OpenClipTextEncoder` computes the same feature with
`open_clip_torch` (model `ViT-B-16-quickgelu`, whose tokenizer ships with the package and works offline).
Weights are never fetched implicitly: pass a local checkpoint file, or `openai` to let open_clip download (or
read from the Hugging Face cache) the OpenAI weights.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from lerobot_obsbench.errors import ObsBenchError

CLIP_MODEL = "ViT-B-16-quickgelu"
CLIP_TEXT_DIM = 512
INSTALL_HINT = "pip install 'lerobot_policy_obsbench[rlbench]' (or pip install open_clip_torch)"


class TextEncoderError(ObsBenchError, RuntimeError):
    pass


class TextEncoder(Protocol):
    """What the importer and the RLBench evaluation need: a name (kept in the dataset's metadata), the feature
    size, and a batch of texts -> (N, dim) float32 features."""

    name: str
    dim: int

    def encode(self, texts: list[str]) -> np.ndarray: ...


class OpenClipTextEncoder:
    """An open_clip model's `encode_text` (not normalised, float32), cached per text."""

    def __init__(self, model, tokenizer, name: str):
        self.model, self.tokenizer, self.name = model.eval(), tokenizer, name
        self.dim = int(model.text_projection.shape[1])
        self._cache: dict[str, np.ndarray] = {}

    def encode(self, texts: list[str]) -> np.ndarray:
        import torch

        new = [t for t in dict.fromkeys(texts) if t not in self._cache]
        if new:
            with torch.no_grad():
                features = self.model.encode_text(self.tokenizer(new), normalize=False).float().cpu().numpy()
            self._cache.update(zip(new, features, strict=True))
        return np.stack([self._cache[t] for t in texts]).astype(np.float32)


def _open_clip():
    try:
        import open_clip
    except ImportError as error:
        raise TextEncoderError(f"language goals need open_clip_torch ({error}): {INSTALL_HINT}") from error
    return open_clip


def load_clip_text_encoder(weights: str) -> OpenClipTextEncoder:
    """CLIP ViT-B/16's text tower from `weights`: a local open_clip / OpenAI checkpoint file, or `openai` (the
    OpenAI weights through open_clip's Hub download or cache; fails clearly offline)."""
    open_clip = _open_clip()
    if weights != "openai" and not Path(weights).is_file():
        raise TextEncoderError(
            f"CLIP weights {weights!r} not found: pass a local ViT-B/16 checkpoint file (e.g. the OpenAI "
            "ViT-B-16.pt, or open_clip_pytorch_model.bin from timm/vit_base_patch16_clip_224.openai), or 'openai' "
            "to download them where the Hub is reachable"
        )
    try:
        model = open_clip.create_model(CLIP_MODEL, pretrained=weights)
    except Exception as error:  # open_clip raises RuntimeError / OSError / HF errors, all for the same reason
        raise TextEncoderError(
            f"cannot load CLIP {CLIP_MODEL} weights from {weights!r} ({type(error).__name__}: {error}). Offline, "
            "download them once where the Hub is reachable (huggingface-cli download "
            "timm/vit_base_patch16_clip_224.openai) or pass a local checkpoint file."
        ) from error
    return OpenClipTextEncoder(model, open_clip.get_tokenizer(CLIP_MODEL), f"open_clip:{CLIP_MODEL}:{weights}")
