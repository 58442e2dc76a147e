"""The auxiliary heads' losses: the gap head and the closing head learn, by Huber loss, the
simulator's gap and closing speed stored with each transition (never a network input).

Both read the hidden layer the Q-values read, so their gradients shape its features.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from agent_client.rewards import CONTROL_PERIOD
from agent_client.rl.config import Config
from agent_client.rl.losses.term import Forward, LossTerm
from agent_client.rl.network import CLOSING_HEAD_SCALE, GAP_HEAD_SCALE

__all__ = [
    "GAP_NAME", "CLOSING_NAME", "GAP_HEAD_RANGE", "CLOSING_HEAD_RANGE", "gap_head_target", "closing_speed",
    "closing_head_target", "gap_head_loss", "closing_head_loss", "gap_term", "closing_term",
]  # fmt: skip

GAP_NAME = "losses/gap_head"
CLOSING_NAME = "losses/closing_head"
GAP_HEAD_RANGE = (1.0, 150.0)  # [m] the gap head's target is clipped to this: beyond 150 m only "far" matters
CLOSING_HEAD_RANGE = 20.0  # [m/s] its target is clipped to +-this (a car cutting in jumps the gap)


def gap_head_target(gap: torch.Tensor) -> torch.Tensor:
    """The gap head's training target for gaps [m]: log(clip(gap, 1, 150) / 55)."""
    return torch.log(gap.clamp(*GAP_HEAD_RANGE) / GAP_HEAD_SCALE)


def closing_speed(gaps: torch.Tensor, next_gaps: torch.Tensor, dt: float) -> torch.Tensor:
    """[m/s] (gap - next gap) / ``dt``, from gaps stored one control step apart: positive
    while the host gains on the lead (NaN where none were stored)."""
    return (gaps - next_gaps) / dt


def closing_head_target(gaps: torch.Tensor, next_gaps: torch.Tensor, dt: float) -> torch.Tensor:
    """The closing head's training target: :func:`closing_speed`, clipped to +-20 m/s, over 5 m/s."""
    closing = closing_speed(gaps, next_gaps, dt)
    return closing.clamp(-CLOSING_HEAD_RANGE, CLOSING_HEAD_RANGE) / CLOSING_HEAD_SCALE


def gap_head_loss(out: Forward) -> torch.Tensor:
    """The gap head's Huber loss to :func:`gap_head_target` of the stored gaps.

    Raises:
        ValueError: the network has no gap head.
    """
    if out.gap is None:
        raise ValueError("the gap head's loss needs a network with the head (Config.aux_gap > 0)")
    return F.smooth_l1_loss(out.gap, gap_head_target(out.batch.gaps.to(out.device)))


def closing_head_loss(out: Forward) -> torch.Tensor:
    """The closing head's Huber loss to :func:`closing_head_target` of the stored gaps.

    Raises:
        ValueError: the network has no closing head.
    """
    if out.closing is None:
        raise ValueError("the closing head's loss needs a network with the head (Config.aux_closing > 0)")
    b, dev = out.batch, out.device
    target = closing_head_target(b.gaps.to(dev), b.next_gaps.to(dev), CONTROL_PERIOD)
    return F.smooth_l1_loss(out.closing, target)


def gap_term(cfg: Config) -> LossTerm:
    """The gap head's loss, times ``cfg.aux_gap``."""
    return LossTerm(GAP_NAME, cfg.aux_gap, gap_head_loss)


def closing_term(cfg: Config) -> LossTerm:
    """The closing head's loss, times ``cfg.aux_closing``."""
    return LossTerm(CLOSING_NAME, cfg.aux_closing, closing_head_loss)
