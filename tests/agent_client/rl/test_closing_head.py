"""The auxiliary closing-speed head (``--aux-closing``): a training signal and an inspectable output, never an input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rewards import CONTROL_PERIOD
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.learner import Learner
from agent_client.rl.losses.aux_heads import closing_head_target
from agent_client.rl.network import QNetwork
from agent_client.rl.replay import ReplayMemory
from agent_client.stacker import FrameStacker


def test_the_head_does_not_change_the_outputs_and_draws_no_other_initial_weights():
    rng = np.random.default_rng(0)
    frames = torch.from_numpy(rng.integers(0, 256, (3, 8, FRAME_H, FRAME_W), dtype=np.uint8))
    speeds = torch.from_numpy(rng.uniform(0, 30, (3, 8)).astype(np.float32))
    torch.manual_seed(3)
    gap_only = QNetwork(gap_head=True)
    torch.manual_seed(3)
    both = QNetwork(gap_head=True, closing_head=True)
    assert set(both.state_dict()) - set(gap_only.state_dict()) == {"closing_head.weight", "closing_head.bias"}
    for name, t in gap_only.state_dict().items():
        torch.testing.assert_close(both.state_dict()[name], t, rtol=0, atol=0)
    q, gap, closing = both.with_heads(frames, speeds)
    q0, gap0 = gap_only.q_and_gap(frames, speeds)
    torch.testing.assert_close(q, q0, rtol=0, atol=0)
    torch.testing.assert_close(gap, gap0, rtol=0, atol=0)
    assert closing is not None and closing.shape == (3,)
    torch.testing.assert_close(QNetwork.closing_estimate(closing), 5.0 * closing)
    q, gap, closing = QNetwork().with_heads(frames, speeds)
    assert gap is None and closing is None and q.shape == (3, 21)


def test_the_target_is_the_clipped_closing_speed_over_five():
    gaps = torch.tensor([55.0, 55.0, 30.0, 10.0, 60.0, float("nan")])
    next_gaps = torch.tensor([55.0, 54.8, 30.3, 1.0, 95.0, 50.0])
    # closing speeds over one control step (0.1 s): 0, 2, -3, 90 (clipped to 20), -350 (clipped to -20)
    expected = np.array([0.0, 2.0, -3.0, 20.0, -20.0, np.nan]) / 5.0
    np.testing.assert_allclose(closing_head_target(gaps, next_gaps, 0.1).numpy(), expected, rtol=1e-4, atol=1e-5)


@pytest.mark.slow  # over ~5 s alone
def test_the_closing_loss_teaches_the_head_the_closing_speed_from_the_gaps_one_step_apart(tmp_path):
    """Frames whose brightness encodes the gap's fall over the next step: the head can read it
    only if the target pairs each observation's gap with the next one's; the loss is logged."""
    cfg = Config(reward="gap", aux_closing=1.0, total_steps=10, batch_size=16, learning_rate=1e-3, torch_threads=1, log_every=1)
    learner = Learner(cfg, tmp_path, trainer="single")
    assert learner.q.closing_head is not None and learner.q.gap_head is None
    rng = np.random.default_rng(0)
    closing = rng.uniform(-8.0, 8.0, 300)  # [m/s] from each observation to the next
    gaps = 60.0 - np.concatenate([[0.0], np.cumsum(closing * CONTROL_PERIOD)])
    memory, stacker = ReplayMemory(512, 8, 1, gaps=True), FrameStacker(8, 1)

    def obs(i: int) -> dict[str, np.ndarray]:
        return stacker.push(np.full((FRAME_H, FRAME_W), int(128 + 12 * closing[min(i, len(closing) - 1)]), np.uint8), 20.0)

    memory.start(obs(0), gaps[0])
    for i in range(1, len(closing)):
        memory.add(10, 0.0, False, False, obs(i), gaps[i])

    def error() -> float:
        b = memory.sample(64, np.random.default_rng(7), 1, 0.99)
        with torch.no_grad():
            _, _, raw = learner.q.with_heads(b.frames, b.speeds)
        assert raw is not None
        return float((raw - closing_head_target(b.gaps, b.next_gaps, CONTROL_PERIOD)).abs().mean())

    before = error()
    for _ in range(200):
        losses = learner.update(memory.sample(16, rng, 1, 0.99), log_step=1)
    assert losses is not None and set(losses[2]) == {"losses/closing_head"}
    assert error() < 0.3 * before
    learner.close()


def test_config_checks_the_weight_and_the_trainer_and_the_replay_keeps_gaps_for_it():
    with pytest.raises(ConfigError, match="aux_closing"):
        Config(aux_closing=-0.5)
    with pytest.raises(ConfigError, match="--aux-closing 1 needs the single-stream trainer") as e:
        Config(aux_closing=1.0, servers=2)
    assert e.value.field == "aux_closing"
    assert Config(aux_closing=1.0).stores_gaps and Config(aux_gap=1.0).stores_gaps and not Config().stores_gaps


def test_the_controller_logs_the_estimate_beside_the_gap_heads():
    from agent_client.controllers.ddqn import DDQNController

    torch.manual_seed(0)
    ctl = DDQNController(QNetwork(gap_head=True, closing_head=True), Config(aux_gap=1.0, aux_closing=1.0))
    assert ctl.log_columns == ("gap_est", "closing_est")
    assert DDQNController(QNetwork(closing_head=True), Config(aux_closing=1.0)).log_columns == ("closing_est",)
    image = np.random.default_rng(0).integers(0, 256, (200, 200), dtype=np.uint8)
    force = ctl({"image": image.tobytes(), "image_shape": [200, 200, 1], "v_host": 25.0})
    assert -1.0 <= force <= 1.0 and len(ctl.log_values) == 2 and ctl.log_values[0] > 0.0
