"""The Q-network (the paper's Figure 4, scaled to a 2-core CPU) and its one inference path.

Every greedy decision, in training, in the trainer's evaluation and in ``vacc drive``,
goes through :func:`greedy_action`, so they compute the same numbers to the last digit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn as nn

from agent_client.preprocess import FRAME_H, FRAME_W
from protocol.constants import FORCES, N_ACTIONS

__all__ = ["QNetwork", "FORCES", "N_ACTIONS", "greedy_action", "linear_schedule"]



class QNetwork(nn.Module):
    """Convolutions over the frame stack (frames as channels); the host-speed sequence
    joins at the fully connected layers; 21 Q-values out.

    conv 5x5/4 (16) -> conv 4x4/2 (32) -> conv 3x3/2 (64) -> 2560 features
    [2560 features, 8 speeds / speed_scale] -> fc 256 -> fc 21

    About 693 k parameters (2.8 MB as float32). The first layer is a 5x5 kernel at
    stride 4 rather than Atari's 8x8: on one CPU thread it cut a batch-32 update
    from about 80 ms to 58 ms and the batch-1 forward by about 15 %.

    The forward pass takes frames and speeds only: there is no way to give it the gap.
    """

    def __init__(self, frame_stack: int = 8, n_actions: int = N_ACTIONS, speed_scale: float = 30.0):
        super().__init__()
        self.speed_scale = speed_scale
        self.conv = nn.Sequential(
            nn.Conv2d(frame_stack, 16, 5, stride=4),
            nn.ReLU(),
            nn.Conv2d(16, 32, 4, stride=2),
            nn.ReLU(),
            nn.Conv2d(32, 64, 3, stride=2),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n_conv = self.conv(torch.zeros(1, frame_stack, FRAME_H, FRAME_W)).shape[1]
        self.fc = nn.Sequential(nn.Linear(n_conv + frame_stack, 256), nn.ReLU(), nn.Linear(256, n_actions))

    @classmethod
    def of(cls, cfg: Any) -> QNetwork:
        """The network a :class:`~agent_client.rl.config.Config` describes."""
        return cls(cfg.frame_stack, N_ACTIONS, cfg.speed_scale)

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor) -> torch.Tensor:
        """Q-values.

        Args:
            frames: uint8 ``[B, frame_stack, 105, 150]``.
            speeds: host speeds [m/s], ``[B, frame_stack]``.

        Returns:
            ``[B, 21]`` Q-values, one per force level -1.0 .. 1.0.
        """
        x = self.conv(frames.float() / 255.0)  # [B, 2560]
        v = speeds.float() / self.speed_scale  # [B, S]
        return self.fc(torch.cat([x, v], dim=1))  # [B, A]


def greedy_action(q: QNetwork, frames: np.ndarray, speeds: np.ndarray) -> int:
    """argmax_a Q(s, a) for one stacked observation (frames ``[S, H, W]``, speeds ``[S]``)."""
    device = next(q.parameters()).device
    with torch.inference_mode():
        qv = q(torch.from_numpy(frames).to(device)[None], torch.from_numpy(speeds).to(device)[None])  # [1, A]
    return int(qv.argmax(dim=1).item())


def linear_schedule(start_e: float, end_e: float, duration: int, t: int) -> float:
    """ε at step ``t``: linear from ``start_e`` to ``end_e`` over ``duration`` steps."""
    slope = (end_e - start_e) / duration
    return max(slope * t + start_e, end_e) if end_e < start_e else min(slope * t + start_e, end_e)
