"""CLIP prompt embeddings, computed once per prompt (SDS guidance and LoRA training)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import torch


class PromptEmbeddings:
    """``self(prompt)``: the [1, tokens, dim] CLIP hidden states of a prompt, cached.

    Prompts are padded to the tokenizer's full length, as Stable Diffusion was trained.
    ``dtype``: the embeddings' dtype (None: the text encoder's own).
    """

    def __init__(
        self,
        tokenizer: Any,
        text_encoder: Any,
        device: torch.device | str,
        dtype: torch.dtype | None = None,
    ) -> None:
        self.tokenizer, self.text_encoder = tokenizer, text_encoder
        self.device, self.dtype = device, dtype
        self._cache: dict[str, torch.Tensor] = {}

    @torch.no_grad()
    def __call__(self, prompt: str) -> torch.Tensor:
        cached = self._cache.get(prompt)
        if cached is None:
            ids = self.tokenizer(
                prompt,
                padding="max_length",
                max_length=self.tokenizer.model_max_length,
                truncation=True,
                return_tensors="pt",
            ).input_ids
            cached = self.text_encoder(ids.to(self.device))[0]
            if self.dtype is not None:
                cached = cached.to(self.dtype)
            self._cache[prompt] = cached
        return cached

    def __iter__(self) -> Iterator[str]:
        """The prompts embedded so far."""
        return iter(self._cache)

    def __len__(self) -> int:
        return len(self._cache)

    def batch(self, prompts: list[str]) -> torch.Tensor:
        """[len(prompts), tokens, dim]."""
        return torch.cat([self(p) for p in prompts])
