"""The learner's loss: a sum of named terms, each in its own module, chosen once from the config.

==================  ==========================  ========================  ===================
term                module                      scalar                    active when
==================  ==========================  ========================  ===================
TD (Double DQN)     :mod:`.td`                  ``losses/td_loss``        no teacher
imitation (DAgger)  :mod:`.imitation`           ``losses/teacher_ce``     a teacher
gap head            :mod:`.aux_heads`           ``losses/gap_head``       ``aux_gap`` > 0
closing head        :mod:`.aux_heads`           ``losses/closing_head``   ``aux_closing`` > 0
brake margin        :mod:`.brake_margin`        ``losses/brake_margin``   ``brake_margin`` > 0
==================  ==========================  ========================  ===================

loss = main + aux_gap * gap + aux_closing * closing + brake_margin * margin, summed in this
order, each term computed just before it is added: the order of the sum and of the graph's
nodes is part of what makes a seed give the same weights to the last bit.
"""

from __future__ import annotations

import torch

from agent_client.rl.config import Config
from agent_client.rl.losses.aux_heads import closing_term, gap_term
from agent_client.rl.losses.brake_margin import margin_term
from agent_client.rl.losses.imitation import imitation_term
from agent_client.rl.losses.td import td_term
from agent_client.rl.losses.term import Forward, LossTerm
from agent_client.rl.network import QNetwork

__all__ = ["Forward", "LossTerm", "build_terms", "weighted_sum"]


def build_terms(cfg: Config, q: QNetwork, target: QNetwork, device: torch.device) -> tuple[LossTerm, ...]:
    """The terms ``cfg`` asks for, main term first, in the order they are summed.

    Args:
        cfg: the settings (``teacher``, ``brake_weight``, ``aux_gap``, ``aux_closing``,
            ``brake_margin``, ``gamma``, ``absorbing_terminal``).
        q: the online network (the TD target's next action).
        target: the target network (the TD target's value).
        device: where the networks are.
    """
    terms = [td_term(cfg, q, target) if cfg.teacher == "none" else imitation_term(cfg, device)]
    if cfg.aux_gap > 0.0:
        terms.append(gap_term(cfg))
    if cfg.aux_closing > 0.0:
        terms.append(closing_term(cfg))
    if cfg.brake_margin > 0.0:
        terms.append(margin_term(cfg))
    return tuple(terms)


def weighted_sum(terms: tuple[LossTerm, ...], out: Forward) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """The loss to minimise and each term's own value, in ``terms``' order.

    The main term (weight None) starts the sum as it is; each other is computed, then added
    times its weight, before the next is computed.
    """
    main, *rest = terms
    assert main.weight is None, "the first term is the main one"
    total = main.loss(out)
    values = [total]
    for term in rest:
        assert term.weight is not None, "only the first term is the main one"
        value = term.loss(out)
        values.append(value)
        total = total + term.weight * value
    return total, values
