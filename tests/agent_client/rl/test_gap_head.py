"""The auxiliary gap head (``--aux-gap``): a training signal and an inspectable output, never an input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.learner import Learner
from agent_client.rl.losses.aux_heads import gap_head_target
from agent_client.rl.network import QNetwork
from agent_client.rl.replay import ReplayMemory
from agent_client.stacker import FrameStacker


def _batch(n: int = 4, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    frames = torch.from_numpy(rng.integers(0, 256, (n, 8, FRAME_H, FRAME_W), dtype=np.uint8))
    return frames, torch.from_numpy(rng.uniform(0, 30, (n, 8)).astype(np.float32))


def test_the_head_does_not_change_the_q_values_and_draws_no_other_initial_weights():
    torch.manual_seed(3)
    plain = QNetwork()
    torch.manual_seed(3)
    headed = QNetwork(gap_head=True)
    for name, t in plain.state_dict().items():
        torch.testing.assert_close(headed.state_dict()[name], t, rtol=0, atol=0)
    assert set(headed.state_dict()) - set(plain.state_dict()) == {"gap_head.weight", "gap_head.bias"}
    frames, speeds = _batch()
    q, raw = headed.q_and_gap(frames, speeds)
    torch.testing.assert_close(q, plain(frames, speeds), rtol=0, atol=0)
    torch.testing.assert_close(headed(frames, speeds), q, rtol=0, atol=0)
    assert raw.shape == (4,) and (QNetwork.gap_estimate(raw) > 0).all()
    with pytest.raises(ValueError, match="no gap head"):
        plain.q_and_gap(frames, speeds)


def test_the_target_is_the_log_of_the_clipped_gap():
    t = gap_head_target(torch.tensor([0.0, 1.0, 8.0, 55.0, 150.0, 300.0]))
    expected = np.log(np.array([1.0, 1.0, 8.0, 55.0, 150.0, 150.0]) / 55.0)
    np.testing.assert_allclose(t.numpy(), expected, rtol=1e-6)
    np.testing.assert_allclose(QNetwork.gap_estimate(t).numpy(), [1.0, 1.0, 8.0, 55.0, 150.0, 150.0], rtol=1e-5)


def test_the_replay_keeps_each_observations_gap_apart_from_the_observation(tmp_path):
    memory, stacker = ReplayMemory(64, 8, 1, gaps=True), FrameStacker(8, 1)
    rng = np.random.default_rng(0)
    obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0)
    assert "gap" not in obs and set(obs) == {"frames", "speeds"}
    memory.start(obs, 50.0)
    for i in range(30):
        memory.add(3, 0.0, False, False, stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0), 49.0 - i)
    b = memory.sample(16, np.random.default_rng(1), 1, 0.99)
    np.testing.assert_array_equal(b.gaps.numpy(), 50.0 - b.indices)  # slot i holds the gap of observation i
    path = tmp_path / "replay.npz"
    memory.save(path, 30)
    again = ReplayMemory(64, 8, 1, gaps=True)
    again.load(path)
    np.testing.assert_array_equal(again.gaps[:31], memory.gaps[:31])
    assert memory.nbytes - ReplayMemory(64, 8, 1).nbytes == 64 * 4  # 4 bytes per slot
    plain = ReplayMemory(64, 8, 1)
    plain.start(obs)
    plain.add(3, 0.0, False, False, obs)
    plain.add(3, 0.0, False, False, obs)
    assert np.isnan(plain.sample(2, np.random.default_rng(1)).gaps.numpy()).all()


@pytest.mark.slow  # over ~5 s alone
def test_the_gap_loss_teaches_the_head_the_gap(tmp_path):
    """Frames whose brightness encodes the gap: after some updates the head reads it; the loss is logged."""
    cfg = Config(reward="gap", aux_gap=1.0, total_steps=10, batch_size=16, learning_rate=1e-3, torch_threads=1, log_every=1)
    learner = Learner(cfg, tmp_path, trainer="single")
    assert learner.q.gap_head is not None
    memory, stacker = ReplayMemory(256, 8, 1, gaps=True), FrameStacker(8, 1)
    rng = np.random.default_rng(0)

    def obs_at(gap: float) -> dict[str, np.ndarray]:
        return stacker.push(np.full((FRAME_H, FRAME_W), int(gap), np.uint8), 20.0)

    gaps = rng.uniform(5.0, 120.0, 200)
    memory.start(obs_at(gaps[0]), gaps[0])
    for g in gaps[1:]:
        memory.add(10, 0.0, False, False, obs_at(g), g)

    def error() -> float:
        b = memory.sample(64, np.random.default_rng(7), 1, 0.99)
        with torch.no_grad():
            _, raw = learner.q.q_and_gap(b.frames, b.speeds)
        return float((raw - gap_head_target(b.gaps)).abs().mean())

    before = error()
    for _ in range(150):
        losses = learner.update(memory.sample(16, rng, 1, 0.99), log_step=1)
    assert losses is not None and losses[2] is not None
    assert error() < 0.3 * before
    learner.close()


def test_config_checks_the_weight_and_the_trainer(tmp_path):
    from click.testing import CliRunner

    from agent_client.rl.distributed import train_distributed
    from vacc.cli import main

    with pytest.raises(ConfigError, match="aux_gap"):
        Config(aux_gap=-1.0)
    with pytest.raises(ConfigError, match="--aux-gap 1 needs the single-stream trainer") as e:
        Config(aux_gap=1.0, servers=2)
    assert e.value.field == "aux_gap"
    # --ray with one server passes the config, but its streams store no gaps either
    result = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--aux-gap", "1", "--ray", "--out", str(tmp_path / "r")])
    assert result.exit_code == 2 and "--aux-gap 1 needs the single-stream trainer" in result.output
    with pytest.raises(ValueError, match="aux-gap"):
        train_distributed(Config(aux_gap=1.0), tmp_path / "d", use_ray=True)
    assert not (tmp_path / "r").exists() and not (tmp_path / "d").exists()


@pytest.mark.parametrize("decision", ["argmax", "mean"])
def test_a_decision_from_the_heads_pass_is_the_policys_own(decision):
    from agent_client.actions import make_action_type
    from agent_client.rl.network import Policy

    torch.manual_seed(0)
    q = QNetwork(n_actions=21, n_controls=2, gap_head=True).eval()
    levels = make_action_type("ramp-fine").levels if decision == "mean" else ()
    policy = Policy(q, decision, levels)
    frames, speeds = _batch(8)
    controls = torch.zeros(8, 8, 2)
    controls[:, :, 1] = 30.0
    for i in range(8):
        obs = {"frames": frames[i].numpy(), "speeds": speeds[i].numpy(), "controls": controls[i].numpy()}
        with torch.inference_mode():
            out, _ = q.q_and_gap(frames[i : i + 1], speeds[i : i + 1], controls[i : i + 1])
        assert policy.decide(out[0]) == policy(obs)


def test_a_recorded_drive_keeps_the_controllers_columns():
    from agent_client.controllers.ddqn import DDQNController
    from agent_client.controllers.human_file import RecordingController

    ctl = DDQNController(QNetwork(gap_head=True), Config(aux_gap=1.0))
    wrapped = RecordingController(ctl, None)  # type: ignore[arg-type]  # the recorder is not used here
    assert wrapped.log_columns == ("gap_est",) and wrapped.log_values == ()
    ctl.log_values = (12.5,)
    assert wrapped.log_values == (12.5,)
    assert RecordingController(lambda obs: 0.0, None).log_columns == ()  # type: ignore[arg-type]


def test_a_run_with_the_head_trains_from_a_model_without_one_and_drives_logging_its_estimate(tmp_path):
    import csv

    from click.testing import CliRunner

    from agent_client.rl.checkpoint import load_policy, save_policy
    from agent_client.rl.train import train
    from vacc.cli import main

    base = tmp_path / "base.pt"
    torch.manual_seed(0)
    plain = QNetwork()
    save_policy(plain, Config(), base)
    cfg = Config(
        total_steps=60, learning_starts=20, train_every=4, batch_size=8, buffer_size=200, exploration_steps=40,
        target_sync_every=20, episode_seconds=3.0, checkpoint_every=30, eval_every=0, eval_trajectories=(), log_every=10,
        aux_gap=1.0, init_from=str(base),
    )  # fmt: skip
    train(cfg, tmp_path / "run", progress=False)
    q, saved = load_policy(tmp_path / "run" / "latest.pt")
    assert saved.aux_gap == 1.0 and q.gap_head is not None
    # started from it (a few small updates since), not from a fresh initialisation
    torch.manual_seed(1)
    fresh = QNetwork()
    for name in ("conv.0.weight", "fc.0.weight", "fc.2.weight"):
        trained, start, other = q.state_dict()[name], plain.state_dict()[name], fresh.state_dict()[name]
        assert (trained - start).abs().max() < 5e-3 < (other - start).abs().max(), name
    names = {r["name"] for r in csv.DictReader(open(tmp_path / "run" / "scalars.csv"))}
    assert "losses/gap_head" in names and "losses/td_loss" in names
    log = tmp_path / "drive.csv"
    result = CliRunner().invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(tmp_path / "run" / "latest.pt"),
                                       "--trajectory", "test-1", "--duration", "2", "--log", str(log)])  # fmt: skip
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader(open(log)))
    assert rows[0].keys() >= {"gap", "gap_est"} and len(rows) == 21
    assert all(float(r["gap_est"]) > 0 for r in rows[:-1]) and rows[-1]["gap_est"] == ""  # the last row: no decision
    # a model without the head logs the usual columns only
    result = CliRunner().invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(base), "--trajectory", "test-1", "--duration", "1", "--log", str(log)])
    assert result.exit_code == 0, result.output
    assert "gap_est" not in open(log).readline()
