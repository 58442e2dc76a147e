"""DQfD's large-margin loss toward the full brake in the replayed emergencies
(Hester et al. 2018), beside the TD loss (``Config.brake_margin``).

An emergency is read off the simulator's gaps stored with each transition (never a
network input): a closing speed that only a hard brake still stops :data:`MIN_GAP` short of.
With ``emergency`` "stopping" also a braking lead's stop: a lead braking on to a stand
leaves the host its gap plus the lead's stopping distance (stored too), and a lead that
brakes from speed makes that the tighter bound long before the closing speed says so.
With "graded" the margin asks, in the same emergencies, for any force level that brakes
as hard as the state needs, not for the full brake: a firm stop, not a jolt.
"""

from __future__ import annotations

import math

import torch

from agent_client.actions import EMERGENCY_LEVEL
from agent_client.rewards import CONTROL_PERIOD
from agent_client.rl.config import Config
from agent_client.rl.losses.aux_heads import closing_speed
from agent_client.rl.losses.term import Forward, LossTerm
from protocol.constants import A_MIN, FORCE_LEVELS, MIN_GAP

__all__ = [
    "NAME", "BRAKE_MARGIN", "EMERGENCY_SHARE", "lead_stop_distance", "emergencies", "stopping_emergencies", "needed_deceleration",
    "brake_margin_loss", "margin_loss", "graded_margin_loss", "margin_term",
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


def _stop_need(gaps: torch.Tensor, v_host: torch.Tensor, lead_stops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``[B]`` [m/s^2] the deceleration that stops :data:`MIN_GAP` short of a lead braking on to
    a stand, and ``[B]`` bool where that is defined (a finite stopping distance is kept)."""
    room = gaps - MIN_GAP + lead_stops
    return v_host.square() / (2.0 * room.clamp(min=1e-3)), torch.isfinite(room)


def stopping_emergencies(gaps: torch.Tensor, v_host: torch.Tensor, lead_stops: torch.Tensor) -> torch.Tensor:
    """``[B]`` bool: the states where stopping :data:`MIN_GAP` short of a lead that brakes on
    to a stand (within its stopping distance ``lead_stops`` [m], inf: not braking) needs at
    least :data:`EMERGENCY_SHARE` of the full brake, from the host's speed ``v_host`` [m/s]."""
    need, defined = _stop_need(gaps, v_host, lead_stops)
    return (need >= EMERGENCY_SHARE * -A_MIN) & defined


def needed_deceleration(gaps: torch.Tensor, next_gaps: torch.Tensor, v_host: torch.Tensor, lead_stops: torch.Tensor, dt: float) -> torch.Tensor:
    """``[B]`` [m/s^2] the deceleration that stops :data:`MIN_GAP` short of the lead, the larger
    of the closing speed's (the lead holds its speed) and the braking lead's stop's; inf where
    the host is inside MIN_GAP and closing, 0 where neither applies (NaN gaps or lead stops)."""
    closing = closing_speed(gaps, next_gaps, dt)
    room = gaps - MIN_GAP
    by_closing = torch.where(room > 0.0, closing.square() / (2.0 * room.clamp(min=1e-3)), torch.full_like(room, torch.inf))
    by_closing = torch.where((closing > 0.0) & torch.isfinite(closing), by_closing, torch.zeros_like(room))
    need, defined = _stop_need(gaps, v_host, lead_stops)
    by_stop = torch.where(defined, need, torch.zeros_like(room))
    return torch.maximum(by_closing, by_stop)


def brake_margin_loss(q_all: torch.Tensor, emergency: torch.Tensor, good: torch.Tensor | None = None) -> torch.Tensor:
    """DQfD's large-margin loss toward the full brake, max_a [Q(s, a) + l(a)] - Q(s, brake),
    l = :data:`BRAKE_MARGIN` off the brake and 0 on it, averaged over the ``emergency``
    states of the batch (0 where there is none): 0 once the brake leads by the margin.
    ``good`` ``[B, A]`` (bool) widens the brake to a set: l is 0 on it, and the best of it
    must lead."""
    if good is None:
        good = torch.zeros_like(q_all, dtype=torch.bool)
        good[:, EMERGENCY_LEVEL] = True
    margins = torch.where(good, 0.0, BRAKE_MARGIN)
    best_good = q_all.masked_fill(~good, -torch.inf).max(dim=1).values
    gaps = (q_all + margins).max(dim=1).values - best_good  # [B] >= 0
    w = emergency.to(q_all.dtype)
    return (gaps * w).sum() / w.sum().clamp(min=1.0)


def margin_loss(out: Forward) -> torch.Tensor:
    """:func:`brake_margin_loss` of a batch's Q-values in its :func:`emergencies` (and its
    :func:`stopping_emergencies` where the memory keeps the lead's stopping distances)."""
    b, dev = out.batch, out.device
    emergency = emergencies(b.gaps.to(dev), b.next_gaps.to(dev), CONTROL_PERIOD)  # [B]
    if b.lead_stops is not None:  # kept only with emergency "stopping"
        emergency |= stopping_emergencies(b.gaps.to(dev), b.speeds[:, -1].to(dev), b.lead_stops.to(dev))  # speeds: the newest last
    return brake_margin_loss(out.q, emergency)


def graded_margin_loss(out: Forward) -> torch.Tensor:
    """:func:`brake_margin_loss` toward every force level (of the "levels" action) that brakes
    at least as hard as :func:`needed_deceleration`, in the states that need at least
    :data:`EMERGENCY_SHARE` of the full brake; the full brake always counts."""
    b, dev = out.batch, out.device
    stops = b.lead_stops if b.lead_stops is not None else torch.full_like(b.gaps, torch.nan)
    need = needed_deceleration(b.gaps.to(dev), b.next_gaps.to(dev), b.speeds[:, -1].to(dev), stops.to(dev), CONTROL_PERIOD)  # [B]
    emergency = need >= EMERGENCY_SHARE * -A_MIN
    decel = torch.tensor(FORCE_LEVELS, dtype=out.q.dtype, device=dev) * A_MIN  # [A] m/s^2 of each level (> 0: a brake)
    good = decel[None, :] >= need[:, None]
    good[:, EMERGENCY_LEVEL] = True
    return brake_margin_loss(out.q, emergency, good)


def margin_term(cfg: Config) -> LossTerm:
    """The brake margin's loss, times ``cfg.brake_margin``."""
    return LossTerm(NAME, cfg.brake_margin, graded_margin_loss if cfg.emergency == "graded" else margin_loss)
