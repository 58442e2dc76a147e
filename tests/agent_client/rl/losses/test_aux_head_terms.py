"""The auxiliary heads' terms: Huber losses of the gap and closing heads to the stored gaps."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from loss_batches import GAPS, NEXT_GAPS, forward, tiny_batch, tiny_net

from agent_client.rl.config import Config
from agent_client.rl.losses.aux_heads import (
    closing_head_loss,
    closing_term,
    gap_head_loss,
    gap_term,
)


def test_the_gap_term_is_the_heads_huber_loss_to_the_log_gap_over_55_m():
    out = forward(tiny_net(0, gap_head=True), tiny_batch())
    target = torch.tensor([math.log(min(max(g, 1.0), 150.0) / 55.0) for g in GAPS])
    torch.testing.assert_close(gap_head_loss(out), F.smooth_l1_loss(out.gap, target), equal_nan=True)
    term = gap_term(Config(aux_gap=0.5))
    assert (term.name, term.weight, term.loss) == ("losses/gap_head", 0.5, gap_head_loss)


def test_the_closing_term_is_the_heads_huber_loss_to_the_clipped_closing_speed_over_5():
    out = forward(tiny_net(0, closing_head=True), tiny_batch())
    closing = [min(max((g - n) / 0.1, -20.0), 20.0) / 5.0 for g, n in zip(GAPS, NEXT_GAPS, strict=True)]  # 0.1 s apart
    torch.testing.assert_close(closing_head_loss(out), F.smooth_l1_loss(out.closing, torch.tensor(closing)), equal_nan=True)
    term = closing_term(Config(aux_closing=2.0))
    assert (term.name, term.weight, term.loss) == ("losses/closing_head", 2.0, closing_head_loss)


def test_a_head_loss_without_its_head_says_so():
    out = forward(tiny_net(0), tiny_batch())
    with pytest.raises(ValueError, match="gap head"):
        gap_head_loss(out)
    with pytest.raises(ValueError, match="closing head"):
        closing_head_loss(out)
