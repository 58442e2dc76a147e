"""The brake-margin term: DQfD's margin loss toward the full brake in the batch's emergencies."""

from __future__ import annotations

import torch
from loss_batches import forward, tiny_batch, tiny_net

from agent_client.rl.config import Config
from agent_client.rl.losses.brake_margin import (
    brake_margin_loss,
    emergencies,
    margin_loss,
    margin_term,
)


def test_the_margin_term_ranks_the_full_brake_in_the_batchs_emergencies():
    b = tiny_batch()
    out = forward(tiny_net(0), b)
    hit = emergencies(b.gaps, b.next_gaps, 0.1)  # stored 0.1 s apart
    assert hit.tolist() == [False, True, True, False]  # 20 m/s at 30 m, 6 m/s at 6 m; not 1 m/s at 80 m, nor opening
    loss = margin_loss(out)
    assert torch.equal(loss, brake_margin_loss(out.q, hit)) and loss > 0.0
    term = margin_term(Config(brake_margin=0.7))
    assert (term.name, term.weight, term.loss) == ("losses/brake_margin", 0.7, margin_loss)
