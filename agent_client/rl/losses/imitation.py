"""DAgger's imitation loss: the cross-entropy of the network's outputs, as logits, to the
teacher's labels (the stored actions of a teacher run).

The main term of a run with a teacher (:data:`NAME`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from agent_client.actions import EMERGENCY_LEVEL, make_action_type
from agent_client.rl.config import Config
from agent_client.rl.losses.term import Forward, LossTerm

__all__ = ["NAME", "LOGIT_NAME", "label_weights", "imitation_term"]

NAME = "losses/teacher_ce"
LOGIT_NAME = "losses/teacher_logit"  # the mean logit of the labels, logged beside it


def label_weights(cfg: Config) -> torch.Tensor:
    """The cross-entropy's weight per label: ``cfg.brake_weight`` on the hardest brake, 1 elsewhere."""
    w = torch.ones(make_action_type(cfg.action).n)
    w[EMERGENCY_LEVEL] = cfg.brake_weight  # action 0 of every type: the full brake (steps: the hard brake step)
    return w


def imitation_term(cfg: Config, device: torch.device) -> LossTerm:
    """The (label-weighted, with ``cfg.brake_weight``) cross-entropy to the teacher's labels."""
    weight = label_weights(cfg).to(device) if cfg.brake_weight != 1.0 else None

    def loss(out: Forward) -> torch.Tensor:
        return F.cross_entropy(out.q, out.batch.actions.to(out.device), weight=weight)

    return LossTerm(NAME, None, loss)
