"""Config.brake_margin: DQfD's large-margin loss on the full brake in the replayed states
whose privileged gaps say only a hard brake still stops short; the TD loss elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from agent_client.actions import EMERGENCY_LEVEL
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config, ConfigError, single_stream_only
from agent_client.rl.learner import Learner
from agent_client.rl.losses.brake_margin import (
    BRAKE_MARGIN,
    EMERGENCY_SHARE,
    brake_margin_loss,
    emergencies,
    graded_margin_loss,
    lead_stop_distance,
    margin_loss,
    needed_deceleration,
    stopping_emergencies,
)
from agent_client.rl.replay import ReplayMemory, _assemble
from agent_client.stacker import FrameStacker
from protocol.constants import A_MIN, FORCE_LEVELS, MIN_GAP
from tests.agent_client.rl.losses.loss_batches import forward, tiny_batch, tiny_net


def test_an_emergency_is_a_closing_speed_that_needs_a_hard_brake_to_stop_short():
    dt = 0.1
    need = EMERGENCY_SHARE * -A_MIN  # [m/s^2]
    room = 30.0
    c = float(np.sqrt(2.0 * need * room))  # the closing speed that needs exactly that
    gaps = torch.tensor([MIN_GAP + room] * 3 + [50.0, 1.5, 1.5, 40.0])
    closing = torch.tensor([c * 1.01, c * 0.99, -c, 0.0, 0.5, -0.5, float("nan")])
    hit = emergencies(gaps, gaps - closing * dt, dt)
    # just over the need; just under; opening; steady; inside MIN_GAP closing; opening; no gap stored
    assert hit.tolist() == [True, False, False, False, True, False, False]


def test_the_margin_loss_is_zero_once_the_brake_leads_by_the_margin_and_counts_only_emergencies():
    q = torch.zeros(3, 21)
    q[0, EMERGENCY_LEVEL] = BRAKE_MARGIN  # leads by the margin: no loss
    q[1, 7] = 2.0  # another action leads: loss 2 + margin
    q[2, 7] = 100.0  # not an emergency: not counted
    loss = brake_margin_loss(q, torch.tensor([True, True, False]))
    assert loss.item() == pytest.approx((0.0 + 2.0 + BRAKE_MARGIN) / 2)
    assert brake_margin_loss(q, torch.zeros(3, dtype=torch.bool)).item() == 0.0


UPDATES = 40


def _trained_q(tmp_path, weight: float) -> torch.Tensor:
    """Q-values, after UPDATES updates with ``brake_margin=weight``, of a fast approach's frame
    (brightness 200) and a slow one's (40); reward 0 everywhere, so only the margin ranks."""
    cfg = Config(reward="gap", brake_margin=weight, total_steps=10, batch_size=16, learning_rate=1e-3, torch_threads=1, gamma=0.0, n_step=1,
                 conv_channels=(4, 8, 8), hidden=32)  # a narrow net: the loss, not the width, is under test
    torch.manual_seed(0)
    learner = Learner(cfg, tmp_path / str(weight), trainer="single")
    memory, stacker = ReplayMemory(512, 8, 1, gaps=True), FrameStacker(8, 1)

    def obs_at(level: int) -> dict[str, np.ndarray]:
        return stacker.push(np.full((FRAME_H, FRAME_W), level, np.uint8), 20.0)

    for closing, level in ((1.0, 40), (25.0, 200)):  # m/s
        stacker.reset()
        gap = 80.0
        memory.start(obs_at(level), gap)
        for _ in range(40):
            gap -= closing * 0.1
            memory.add(10, 0.0, False, True, obs_at(level), gap)
    rng = np.random.default_rng(0)
    for _ in range(UPDATES):
        learner.update(memory.sample(16, rng, 1, 0.0))
    with torch.no_grad():
        q = learner.q(torch.from_numpy(np.stack([obs_at(200)["frames"], obs_at(40)["frames"]])), torch.full((2, 8), 20.0))
    learner.close()
    return q


@pytest.mark.slow  # over ~5 s alone
def test_the_margin_loss_teaches_the_full_brake_where_the_gaps_close_fast(tmp_path):
    q = _trained_q(tmp_path, 1.0)
    lead = q[:, EMERGENCY_LEVEL] - torch.cat([q[:, :EMERGENCY_LEVEL], q[:, EMERGENCY_LEVEL + 1 :]], dim=1).max(dim=1).values
    assert lead[0] > 0.5 * BRAKE_MARGIN  # the fast approach: the brake leads
    control = _trained_q(tmp_path, 0.0)  # the same run without the loss
    assert int(control[0].argmax()) != EMERGENCY_LEVEL


def test_config_checks_the_weight_and_where_it_applies():
    with pytest.raises(ConfigError) as e:
        Config(reward="gap", brake_margin=-1.0)
    assert e.value.field == "brake_margin"
    with pytest.raises(ConfigError, match="teacher") as e:
        Config(reward="eco", brake_margin=1.0, teacher="acc", action="ramp-fine")
    assert e.value.field == "brake_margin"
    found = single_stream_only(Config(reward="gap", brake_margin=1.0))
    assert found is not None and found[0] == "brake_margin"


def test_a_sample_carries_the_gap_one_step_on_within_the_episode():
    memory, stacker = ReplayMemory(64, 8, 1, gaps=True), FrameStacker(8, 1)
    rng = np.random.default_rng(0)
    obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0)
    memory.start(obs, 50.0)
    for i in range(30):
        memory.add(3, 0.0, False, i == 14, obs, 49.0 - i)  # truncated at slot 14: slot 15 is its last observation
        if i == 14:
            memory.start(obs, 200.0)
    b = memory.sample(32, np.random.default_rng(1), 1, 0.99)
    np.testing.assert_array_equal(b.next_gaps.numpy(), memory.gaps[b.indices + 1])
    assert 15 not in b.indices.tolist() and memory.gaps[16] == 200.0  # slot 15 ends the first episode; 16 starts the next


def test_a_braking_leads_stop_is_an_emergency_seconds_before_the_closing_speed_says_so():
    # A distant stop like those ice-gap touched (values made round): host 33.5 m/s, the lead braking at 4 m/s^2
    # from 21 m/s. At 133 m its closing speed of 12.5 m/s needs 0.6 m/s^2 to stop short, and
    # its stop (55 m on) 3.0 m/s^2; at 100 m the stop needs 3.7, past the 3.3 (0.6 of the full
    # brake) that makes an emergency, while the closing speed still says 0.8.
    assert lead_stop_distance(21.0, -4.0) == pytest.approx(21.0**2 / 8.0)
    assert lead_stop_distance(21.0, 0.0) == float("inf") and lead_stop_distance(0.0, -4.0) == float(
        "inf"
    )
    gaps, v_host = torch.tensor([133.0, 100.0, 133.0, 133.0]), torch.full((4,), 33.5)
    stops = torch.tensor(
        [lead_stop_distance(21.0, -4.0), lead_stop_distance(21.0, -4.0), float("inf"), float("nan")]
    )
    assert not emergencies(gaps, gaps - 12.5 * 0.1, 0.1).any()
    hit = stopping_emergencies(gaps, v_host, stops)
    assert not emergencies(gaps[1:2], gaps[1:2] - 12.5 * 0.1, 0.1).any()
    # a lead that is not braking (inf) or a memory without the column (NaN): never
    assert hit.tolist() == [False, True, False, False]


def test_the_margin_loss_adds_the_stopping_emergencies_only_where_the_memory_keeps_lead_stops():
    net, b = tiny_net(0), tiny_batch(0)
    base = margin_loss(forward(net, b))
    assert (
        margin_loss(forward(net, b._replace(lead_stops=torch.full((4,), float("nan"))))).item()
        == base.item()
    )
    near = b._replace(
        gaps=torch.full((4,), 30.0),
        next_gaps=torch.full((4,), 30.0),
        speeds=torch.full_like(b.speeds, 30.0),
    )
    assert (
        margin_loss(forward(net, near)).item() == 0.0
    )  # no closing: no emergency of the closing kind
    stopping = margin_loss(forward(net, near._replace(lead_stops=torch.full((4,), 10.0))))
    assert stopping.item() > 0.0  # 30 m/s toward a lead stopping within 38 m: every state


def test_the_lead_stops_are_kept_sampled_saved_and_loaded_with_the_transitions(tmp_path):
    memory, stacker = ReplayMemory(64, 8, 1, gaps=True, lead_stops=True), FrameStacker(8, 1)
    obs = stacker.push(np.zeros((FRAME_H, FRAME_W), np.uint8), 20.0)
    memory.start(obs, 50.0, lead_stop=float("inf"))
    for i in range(30):
        memory.add(3, 0.0, False, False, obs, 49.0 - i, lead_stop=float(i))
    b = memory.sample(16, np.random.default_rng(1), 1, 0.99)
    assert b.lead_stops is not None
    np.testing.assert_array_equal(b.lead_stops.numpy(), memory.lead_stops[b.indices])
    memory.save(tmp_path / "replay.npz", 30)
    again = ReplayMemory(64, 8, 1, gaps=True, lead_stops=True)
    assert again.load(tmp_path / "replay.npz") == 30
    np.testing.assert_array_equal(again.lead_stops[:31], memory.lead_stops[:31])
    assert memory.lead_stops[0] == float("inf")
    plain = ReplayMemory(64, 8, 1, gaps=True)
    plain.start(obs, 50.0)
    for i in range(30):
        plain.add(3, 0.0, False, False, obs, 49.0 - i)
    assert "lead_stops" not in plain._arrays()
    assert plain.sample(16, np.random.default_rng(1), 1, 0.99).lead_stops is None  # a memory without them samples none
    rng = np.random.default_rng(2)
    mixed = [(m, m._plan(8, rng, 1, 0.99)) for m in (memory, plain)]
    with pytest.raises(ValueError, match="all keep the lead stops or none"):  # half a column would misalign the batch
        _assemble(mixed, memory._buffer(16))


def test_config_checks_the_emergency_kind():
    assert Config(reward="gap", brake_margin=1.0, emergency="stopping").stores_lead_stops
    assert not Config(reward="gap", brake_margin=1.0).stores_lead_stops
    with pytest.raises(ConfigError) as e:
        Config(reward="gap", emergency="stopping")  # no brake margin to apply it
    assert e.value.field == "emergency"
    with pytest.raises(ConfigError) as e:
        Config(reward="gap", brake_margin=1.0, emergency="braking")
    assert e.value.field == "emergency"


def test_the_needed_deceleration_is_the_larger_of_the_closing_speeds_and_the_stops():
    inf, nan = float("inf"), float("nan")
    gaps = torch.tensor([52.0, 52.0, 52.0, 1.5, 52.0])
    closing = torch.tensor([10.0, 0.0, -5.0, 1.0, nan])
    stops = torch.tensor([inf, 48.0, nan, inf, nan])
    need = needed_deceleration(gaps, gaps - closing * 0.1, torch.full((5,), 20.0), stops, 0.1)
    # 10^2 / (2 * 50); 20^2 / (2 * 98); opening and no stop stored; inside MIN_GAP closing; nothing stored
    assert need.tolist() == pytest.approx([1.0, 400.0 / 196.0, 0.0, inf, 0.0])


def test_the_graded_margin_asks_for_a_brake_as_hard_as_needed_not_the_full_brake():
    net, b = tiny_net(0), tiny_batch(0)
    # 30 m/s toward a lead that stops within 38 m of a 30 m gap: 900 / (2 * 66) = 6.8 m/s^2, past the
    # full brake: only the full brake counts, as in the plain margin
    hard = b._replace(gaps=torch.full((4,), 30.0), next_gaps=torch.full((4,), 30.0), speeds=torch.full_like(b.speeds, 30.0),
                      lead_stops=torch.full((4,), 38.0))  # fmt: skip
    out = forward(net, hard)
    assert graded_margin_loss(out).item() == pytest.approx(margin_loss(out).item())
    # 20 m/s, the same room: 400 / 132 = 3.0 m/s^2, under 0.6 of the full brake: no emergency
    assert graded_margin_loss(forward(net, hard._replace(speeds=torch.full_like(b.speeds, 20.0)))).item() == 0.0
    # 24 m/s: 4.4 m/s^2 needed; a network whose best level brakes at 0.9 (5.0 m/s^2) by the margin owes nothing
    firm = hard._replace(speeds=torch.full_like(b.speeds, 24.0))
    q = torch.zeros(4, len(FORCE_LEVELS))
    q[:, 1] = 1.0  # level 1: force -0.9
    out = forward(net, firm)._replace(q=q)
    assert graded_margin_loss(out).item() == 0.0 and margin_loss(out).item() > 0.0  # the plain margin still wants the full brake
    q2 = q.clone()
    q2[:, 3] = 2.0  # level 3 (-0.7: 3.85 m/s^2) leads: not enough
    assert graded_margin_loss(forward(net, firm)._replace(q=q2)).item() == pytest.approx(2.0 + BRAKE_MARGIN - 1.0)


def test_graded_needs_the_force_levels():
    assert Config(reward="gap", brake_margin=1.0, emergency="graded").stores_lead_stops
    with pytest.raises(ConfigError) as e:
        Config(reward="gap", brake_margin=1.0, emergency="graded", action="steps")
    assert e.value.field == "emergency"
