"""The imitation term: the (label-weighted) cross-entropy of the outputs to the teacher's labels."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from loss_batches import forward, tiny_batch, tiny_net

from agent_client.actions import EMERGENCY_LEVEL
from agent_client.rl.config import Config
from agent_client.rl.losses.imitation import NAME, imitation_term, label_weights


def test_the_label_weights_weigh_only_the_full_brake():
    w = label_weights(Config(teacher="acc", brake_weight=4.0))
    assert w.shape == (21,) and w[EMERGENCY_LEVEL] == 4.0
    assert torch.equal(torch.cat([w[:EMERGENCY_LEVEL], w[EMERGENCY_LEVEL + 1 :]]), torch.ones(20))


def test_the_imitation_term_is_the_cross_entropy_to_the_stored_labels():
    q, b = tiny_net(0), tiny_batch()
    out = forward(q, b)
    plain = imitation_term(Config(teacher="acc"), torch.device("cpu"))
    assert (plain.name, plain.weight) == (NAME, None) == ("losses/teacher_ce", None)
    assert torch.equal(plain.loss(out), F.cross_entropy(out.q, b.actions))
    weighted = imitation_term(Config(teacher="acc", brake_weight=4.0), torch.device("cpu")).loss(out)
    w = torch.ones(21)
    w[EMERGENCY_LEVEL] = 4.0
    assert torch.equal(weighted, F.cross_entropy(out.q, b.actions, weight=w))
    assert b.actions[0] == EMERGENCY_LEVEL and weighted != plain.loss(out)  # the batch holds a full-brake label
