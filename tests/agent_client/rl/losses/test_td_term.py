"""The TD term: the Huber loss of the stored actions' Q-values to their Double-DQN targets."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from loss_batches import forward, tiny_batch, tiny_net

from agent_client.rl.config import Config
from agent_client.rl.losses.td import NAME, td_target, td_term


@pytest.mark.parametrize("absorbing", [True, False])
def test_the_td_term_is_the_huber_loss_to_the_double_q_target_written_out(absorbing):
    cfg = Config(gamma=0.9, absorbing_terminal=absorbing)
    q, target, b = tiny_net(0), tiny_net(1), tiny_batch()
    out = forward(q, b)
    with torch.no_grad():
        picked = q(b.next_frames, b.next_speeds).argmax(dim=1, keepdim=True)  # [B, 1] the online net picks
        scored = target(b.next_frames, b.next_speeds).gather(1, picked).squeeze(1)  # [B] the target net scores
    terminal = b.terminal_rewards / (1.0 - 0.9) if absorbing else torch.zeros(4)  # [B]
    y = b.returns + b.discounts * torch.where(b.terminated, terminal, scored)  # [B]
    term = td_term(cfg, q, target)
    assert (term.name, term.weight) == (NAME, None) == ("losses/td_loss", None)
    torch.testing.assert_close(term.loss(out), F.smooth_l1_loss(out.q_taken, y))


def test_the_td_target_carries_no_gradient_and_only_the_online_net_learns():
    q, target, b = tiny_net(0), tiny_net(1), tiny_batch()
    assert not td_target(q, target, b, torch.device("cpu"), 0.99, True).requires_grad
    td_term(Config(), q, target).loss(forward(q, b)).backward()
    assert all(p.grad is None for p in target.parameters())
    assert all(p.grad is not None for p in q.parameters())
