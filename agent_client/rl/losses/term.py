"""What a loss term is and what it reads: one update's online pass over a replay batch."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch

from agent_client.rl.replay import ReplaySamples

__all__ = ["Forward", "LossTerm"]


class Forward(NamedTuple):
    """One update's online pass over a replay batch: what every term reads.

    The batch stays where it was sampled (the CPU); a term moves what it reads to
    ``device``, so a term that reads nothing of it costs no transfer.
    """

    batch: ReplaySamples
    device: torch.device
    q: torch.Tensor  # [B, A] the online network's outputs (Q-values, or logits with a teacher)
    q_taken: torch.Tensor  # [B] the outputs at the stored actions
    gap: torch.Tensor | None  # [B] the gap head's raw output, None without the head
    closing: torch.Tensor | None  # [B] the closing head's raw output, None without the head
    # (recurrent) the next observations' online and target outputs [B, A], from the unrolled
    # sequence: the TD target reads them instead of passing the next frames through the networks
    next_q: tuple[torch.Tensor, torch.Tensor] | None = None


class LossTerm(NamedTuple):
    """A named part of the learner's loss.

    Attributes:
        name: its scalar, ``losses/<name>``.
        weight: its factor in the sum; None for the main term (TD or imitation), which
            the sum starts from as it is.
        loss: the term's scalar loss of one update's :class:`Forward`.
    """

    name: str
    weight: float | None
    loss: Callable[[Forward], torch.Tensor]
