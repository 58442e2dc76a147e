"""A tiny replay batch and networks for the loss terms' unit tests (no server, no memory)."""

from __future__ import annotations

import torch

from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.losses import Forward
from agent_client.rl.network import QNetwork
from agent_client.rl.replay import ReplaySamples

STACK = 2  # frames per observation: small, the terms never look at them
N_ACTIONS = 21
# [m] first gaps and the gaps one 0.1 s step on: closing at 1, 20 and 6 m/s, and opening at
# 5 m/s beyond the gap head's 150 m
GAPS = (80.0, 30.0, 6.0, 200.0)
NEXT_GAPS = (79.9, 28.0, 5.4, 200.5)


def tiny_net(seed: int, gap_head: bool = False, closing_head: bool = False) -> QNetwork:
    """A narrow network (the terms' arithmetic does not depend on the width)."""
    torch.manual_seed(seed)
    return QNetwork(STACK, N_ACTIONS, gap_head=gap_head, closing_head=closing_head, conv_channels=(4, 4, 4), hidden=16)


def tiny_batch(seed: int = 0) -> ReplaySamples:
    """Four transitions: random frames and speeds, one terminated, the gaps above."""
    g = torch.Generator().manual_seed(seed)
    b = len(GAPS)

    def frames() -> torch.Tensor:
        return torch.randint(0, 256, (b, STACK, FRAME_H, FRAME_W), generator=g, dtype=torch.uint8)

    def speeds() -> torch.Tensor:
        return 30.0 * torch.rand((b, STACK), generator=g)

    return ReplaySamples(
        indices=torch.arange(b).numpy(), frames=frames(), speeds=speeds(), controls=torch.zeros((b, STACK, 0)),
        actions=torch.tensor([0, 3, 20, 7]), rewards=torch.rand(b, generator=g), returns=torch.rand(b, generator=g),
        discounts=torch.full((b,), 0.99**3), terminal_rewards=torch.tensor([0.0, -5.0, 0.0, 0.0]),
        terminated=torch.tensor([False, True, False, False]), truncated=torch.tensor([False, False, True, False]),
        next_frames=frames(), next_speeds=speeds(), next_controls=torch.zeros((b, STACK, 0)),
        gaps=torch.tensor(GAPS), next_gaps=torch.tensor(NEXT_GAPS),
    )  # fmt: skip


def forward(q: QNetwork, b: ReplaySamples) -> Forward:
    """The online pass a learner's update makes."""
    q_all, gap, closing = q.with_heads(b.frames, b.speeds, b.controls)  # [B, A], [B] or None each
    q_taken = q_all.gather(1, b.actions[:, None]).squeeze(1)  # [B]
    return Forward(b, torch.device("cpu"), q_all, q_taken, gap, closing)
