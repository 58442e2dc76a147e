"""DQfD's large-margin loss toward the full brake in the replayed emergencies
(Hester et al. 2018), beside the TD loss (``Config.brake_margin``).

An emergency is read off the simulator's gaps stored with each transition (never a
network input): a closing speed that only a hard brake still stops :data:`MIN_GAP` short of.
With ``emergency`` "stopping" also a braking lead's stop: a lead braking on to a stand
leaves the host its gap plus the lead's stopping distance (stored too), and a lead that
brakes from speed makes that the tighter bound long before the closing speed says so.
"""

from __future__ import annotations

import math

import torch

from agent_client.actions import EMERGENCY_LEVEL
from agent_client.rewards import CONTROL_PERIOD
from agent_client.rl.config import Config
from agent_client.rl.losses.aux_heads import closing_speed
from agent_client.rl.losses.term import Forward, LossTerm
from protocol.constants import A_MIN, MIN_GAP

__all__ = [
    "NAME", "BRAKE_MARGIN", "EMERGENCY_SHARE", "lead_stop_distance", "emergencies", "stopping_emergencies", "brake_margin_loss",
    "margin_loss", "margin_term",
]  # fmt: skip

NAME = "losses/brake_margin"
# DQfD's margin (Hester et al. 2018: 0.8) by which the full brake must lead every other
# action in an emergency, and the share of the full brake's deceleration that makes a state
# one (3.3 m/s^2: about ISO 15622's 3.5 m/s^2 ACC limit, past which the ACC itself would
# need the driver).
BRAKE_MARGIN = 0.8
EMERGENCY_SHARE = 0.6


def emergencies(gaps: torch.Tensor, next_gaps: torch.Tensor, dt: float) -> torch.Tensor:
    """``[B]`` bool: the states whose closing speed, (gap - next gap) / ``dt``, needs at least
    :data:`EMERGENCY_SHARE` of the full brake to stop :data:`MIN_GAP` short of the lead (at
    the lead's speed; inside MIN_GAP and closing: always). NaN gaps (none stored): never."""
    closing = closing_speed(gaps, next_gaps, dt)  # [B] m/s, NaN where no gap is stored
    room = gaps - MIN_GAP
    need = closing.square() / (2.0 * room.clamp(min=1e-3))
    hit = (closing > 0.0) & ((room <= 0.0) | (need >= EMERGENCY_SHARE * -A_MIN))
    return hit & torch.isfinite(closing)


def lead_stop_distance(v_lead: float, a_lead: float) -> float:
    """[m] how far the lead travels braking on to a stop at its present deceleration:
    v^2 / (2 |a|); inf while it is not braking (a >= 0) or is already standing."""
    if a_lead >= 0.0 or v_lead <= 0.0:
        return math.inf
    return v_lead * v_lead / (2.0 * -a_lead)


def stopping_emergencies(gaps: torch.Tensor, v_host: torch.Tensor, lead_stops: torch.Tensor) -> torch.Tensor:
    """``[B]`` bool: the states where stopping :data:`MIN_GAP` short of a lead that brakes on
    to a stand (within its stopping distance ``lead_stops`` [m], inf: not braking) needs at
    least :data:`EMERGENCY_SHARE` of the full brake, from the host's speed ``v_host`` [m/s]."""
    room = gaps - MIN_GAP + lead_stops
    need = v_host.square() / (2.0 * room.clamp(min=1e-3))
    return (need >= EMERGENCY_SHARE * -A_MIN) & torch.isfinite(room)


def brake_margin_loss(q_all: torch.Tensor, emergency: torch.Tensor) -> torch.Tensor:
    """DQfD's large-margin loss toward the full brake, max_a [Q(s, a) + l(a)] - Q(s, brake),
    l = :data:`BRAKE_MARGIN` off the brake and 0 on it, averaged over the ``emergency``
    states of the batch (0 where there is none): 0 once the brake leads by the margin."""
    margins = torch.full_like(q_all[0], BRAKE_MARGIN)
    margins[EMERGENCY_LEVEL] = 0.0
    gaps = (q_all + margins).max(dim=1).values - q_all[:, EMERGENCY_LEVEL]  # [B] >= 0
    w = emergency.to(q_all.dtype)
    return (gaps * w).sum() / w.sum().clamp(min=1.0)


def margin_loss(out: Forward) -> torch.Tensor:
    """:func:`brake_margin_loss` of a batch's Q-values in its :func:`emergencies` (and its
    :func:`stopping_emergencies` where the memory keeps the lead's stopping distances)."""
    b, dev = out.batch, out.device
    emergency = emergencies(b.gaps.to(dev), b.next_gaps.to(dev), CONTROL_PERIOD)  # [B]
    if b.lead_stops is not None:  # NaN in a memory that keeps none: no emergency
        emergency |= stopping_emergencies(b.gaps.to(dev), b.speeds[:, -1].to(dev), b.lead_stops.to(dev))  # speeds: the newest last
    return brake_margin_loss(out.q, emergency)


def margin_term(cfg: Config) -> LossTerm:
    """The brake margin's loss, times ``cfg.brake_margin``."""
    return LossTerm(NAME, cfg.brake_margin, margin_loss)
