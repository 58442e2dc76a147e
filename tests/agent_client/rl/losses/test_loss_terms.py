"""The loss as a sum of named terms: which the config picks, in which order, and the sum to the bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from loss_batches import forward, tiny_batch, tiny_net

from agent_client.rl.config import Config
from agent_client.rl.losses import build_terms, weighted_sum


@pytest.mark.parametrize(
    ("settings", "expected"),
    [
        ({}, [("losses/td_loss", None)]),
        ({"teacher": "acc", "brake_weight": 3.0}, [("losses/teacher_ce", None)]),
        ({"aux_closing": 2.0, "aux_gap": 0.5}, [("losses/td_loss", None), ("losses/gap_head", 0.5), ("losses/closing_head", 2.0)]),
        ({"brake_margin": 0.7, "aux_gap": 1.0}, [("losses/td_loss", None), ("losses/gap_head", 1.0), ("losses/brake_margin", 0.7)]),
        ({"teacher": "acc", "aux_closing": 1.5}, [("losses/teacher_ce", None), ("losses/closing_head", 1.5)]),
    ],
)
def test_the_config_picks_the_terms_main_first(settings, expected):
    terms = build_terms(Config(**settings), tiny_net(0), tiny_net(1), torch.device("cpu"))
    assert [(t.name, t.weight) for t in terms] == expected


def test_the_sum_is_main_plus_each_weighted_term_in_order_to_the_bit():
    cfg = Config(aux_gap=0.5, aux_closing=2.0, brake_margin=0.7)
    b = tiny_batch()
    q, target = tiny_net(0, gap_head=True, closing_head=True), tiny_net(1, gap_head=True, closing_head=True)
    terms = build_terms(cfg, q, target, torch.device("cpu"))
    total, values = weighted_sum(terms, forward(q, b))
    assert len(values) == 4 and torch.equal(total, ((values[0] + 0.5 * values[1]) + 2.0 * values[2]) + 0.7 * values[3])
    total.backward()
    grads = [p.grad.clone() for p in q.parameters()]
    q.zero_grad()
    by_hand = forward(q, b)  # the same graph, written out
    loss = terms[0].loss(by_hand)
    loss = loss + 0.5 * terms[1].loss(by_hand)
    loss = loss + 2.0 * terms[2].loss(by_hand)
    loss = loss + 0.7 * terms[3].loss(by_hand)
    loss.backward()
    assert all(torch.equal(g, p.grad) for g, p in zip(grads, q.parameters(), strict=True))


def test_an_update_logs_each_term_by_its_name(tmp_path):
    from agent_client.rl.learner import Learner
    from agent_client.rl.replay import ReplayMemory
    from agent_client.stacker import FrameStacker

    learner = Learner(Config(aux_gap=1.0, aux_closing=0.5, brake_margin=0.7, torch_threads=1), tmp_path)
    try:
        memory, stacker = ReplayMemory(64, 8, 1, gaps=True), FrameStacker(8, 1)
        rng = np.random.default_rng(0)
        gap = 40.0
        memory.start(stacker.push(rng.integers(0, 256, (105, 150), dtype=np.uint8), 20.0), gap)
        for i in range(20):
            gap -= 1.5  # closing at 15 m/s
            memory.add(i % 21, 0.0, False, False, stacker.push(rng.integers(0, 256, (105, 150), dtype=np.uint8), 20.0), gap)
        losses = learner.update(memory.sample(8, rng, 1, 0.99), log_step=1)
    finally:
        learner.close()
    assert losses is not None and set(losses.terms) == {"losses/gap_head", "losses/closing_head", "losses/brake_margin"}
    assert all(np.isfinite([losses.main, losses.taken, *losses.terms.values()]))
