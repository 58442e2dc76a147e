"""The DDQN learner: replay memory, target, checkpoints, privileged-state guard."""

from __future__ import annotations

import dataclasses
import inspect
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from agent_client.actions import ACTION_TYPES
from agent_client.controllers.ddqn import DDQNController
from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.checkpoint import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    CheckpointWriteError,
    digest,
    load_policy,
    save_policy,
    write_atomically,
)
from agent_client.rl.config import Config
from agent_client.rl.losses.td import double_dqn_target
from agent_client.rl.network import (
    FORCES,
    QNetwork,
    ScaledFrames,
    batch_of_one,
    linear_schedule,
    scale_frames,
)
from agent_client.rl.replay import ReplayMemory
from agent_client.stacker import FrameStacker

FRAME_BYTES = FRAME_H * FRAME_W  # one preprocessed frame, uint8
MODELS_DIR = Path(__file__).parents[3] / "models"


def _fill(memory: ReplayMemory, rng: np.random.Generator, lengths: list[int], ends: list[str], preroll: int = 0):
    """Play synthetic episodes into ``memory`` (each after ``preroll`` frames of pre-roll, as
    the env's info["preroll"] gives them); return each slot's expected stack."""
    stacker = FrameStacker(memory.frame_stack, memory.stack_stride)
    expected: dict[int, dict[str, np.ndarray]] = {}
    flags: dict[int, tuple[bool, bool]] = {}
    for n, end in zip(lengths, ends, strict=True):
        stacker.reset()
        for _ in range(preroll):
            stacked = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), float(rng.uniform(0, 40)))
            memory.warm({k: v[-1:] for k, v in stacked.items()})
        frame = rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
        obs = stacker.push(frame, float(rng.uniform(0, 40)))
        memory.start(obs)
        expected[memory.total - 1] = obs
        for k in range(n):
            frame = rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
            next_obs = stacker.push(frame, float(rng.uniform(0, 40)))
            last = k == n - 1
            terminated, truncated = last and end == "terminated", last and end == "truncated"
            flags[memory.total - 1] = (terminated, truncated)
            memory.add(int(rng.integers(21)), float(rng.uniform(-1, 1)), terminated, truncated, next_obs)
            expected[memory.total - 1] = next_obs
    return expected, flags


@pytest.mark.parametrize(("stride", "preroll"), [(1, 0), (3, 0), (2, 14), (3, 5)])
def test_replay_rebuilds_the_env_stacks_across_episode_boundaries(stride, preroll):
    rng = np.random.default_rng(0)
    memory = ReplayMemory(60 + 5 * preroll, 8, stride)
    expected, _ = _fill(memory, rng, [5, 1, 30, 12, 40], ["terminated", "truncated", "truncated", "terminated", "cut"], preroll)
    checked = 0
    for i, obs in expected.items():
        pos = memory.pos[i % memory.capacity]
        if i - stride * min(7, pos // stride) < memory.total - memory.capacity:
            continue  # some of its frames were overwritten
        frames, speeds = memory.stack(np.array([i]))
        np.testing.assert_array_equal(frames[0], obs["frames"])
        np.testing.assert_array_equal(speeds[0], obs["speeds"])
        checked += 1
    assert checked > 40


@pytest.mark.parametrize("preroll", [0, 14])
def test_replay_samples_whole_valid_transitions_only(preroll):
    rng = np.random.default_rng(1)
    memory = ReplayMemory(50 + 4 * preroll, 8, 2)
    expected, flags = _fill(memory, rng, [10, 25, 3, 20], ["terminated", "terminated", "truncated", "cut"], preroll)
    batch = memory.sample(256, rng)
    for b, i in enumerate(batch.indices):
        assert i in flags, "sampled an episode's last observation, or a pre-roll frame, as a start"
        np.testing.assert_array_equal(batch.frames[b], expected[i]["frames"])
        np.testing.assert_array_equal(batch.next_frames[b], expected[i + 1]["frames"])
        np.testing.assert_array_equal(batch.next_speeds[b], expected[i + 1]["speeds"])
        assert (bool(batch.terminated[b]), bool(batch.truncated[b])) == flags[i]
    assert batch.truncated.any() and batch.terminated.any()
    assert not (batch.truncated & batch.terminated).any()


def test_replay_bytes_per_transition_within_1_1_frames():
    memory = ReplayMemory(10_000, 8, 1)
    scalars = 4 + 1 + 4 + 1 + 1  # speed f32, action u8, reward f32, terminated, truncated
    per_transition = memory.nbytes / memory.capacity
    assert per_transition <= 1.1 * (FRAME_BYTES + scalars)
    assert per_transition >= FRAME_BYTES


def test_replay_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    memory = ReplayMemory(40, 8, 1)
    _fill(memory, rng, [30, 20], ["truncated", "cut"])
    memory.save(tmp_path / "replay.npz", step=50)
    again = ReplayMemory(40, 8, 1)
    assert again.load(tmp_path / "replay.npz") == 50
    assert again.total == memory.total and again.transitions == memory.transitions
    for name, a in memory._arrays().items():
        np.testing.assert_array_equal(getattr(again, name), a)
    with pytest.raises(InputFileError, match="capacity"):
        ReplayMemory(41, 8, 1).load(tmp_path / "replay.npz")
    (tmp_path / "bad.npz").write_bytes((tmp_path / "replay.npz").read_bytes()[:1000])
    with pytest.raises(InputFileError, match="bad.npz"):
        ReplayMemory(40, 8, 1).load(tmp_path / "bad.npz")


def test_double_dqn_target_by_hand():
    rewards = torch.tensor([1.0, 2.0, 3.0, -1.0])
    terminated = torch.tensor([False, True, False, True])
    next_q_online = torch.tensor([[1.0, 5.0], [3.0, 2.0], [0.0, 1.0], [9.0, 0.0]])  # [B, A]
    next_q_target = torch.tensor([[10.0, 20.0], [30.0, 40.0], [50.0, 60.0], [70.0, 80.0]])  # [B, A]
    gamma = torch.full((4,), 0.9)
    y = double_dqn_target(rewards, terminated, next_q_online, next_q_target, gamma, torch.zeros(4))
    # online argmax: 1, -, 1, -; the target net scores them: 20, 60; terminations do not bootstrap
    np.testing.assert_allclose(y.numpy(), [1 + 0.9 * 20, 2.0, 3 + 0.9 * 60, -1.0], rtol=1e-6)
    absorbing = rewards / (1 - 0.9)  # the terminal reward forever
    y = double_dqn_target(rewards, terminated, next_q_online, next_q_target, gamma, absorbing)
    np.testing.assert_allclose(y.numpy(), [19.0, 2.0 / 0.1, 57.0, -1.0 / 0.1], rtol=1e-5)
    # plain DQN (max of the target net) would give 40 and 80 in rows 1 and 3
    y = double_dqn_target(rewards, torch.zeros(4, dtype=torch.bool), next_q_online, next_q_target, gamma, torch.zeros(4))
    np.testing.assert_allclose(y.numpy(), [19.0, 2 + 0.9 * 30, 57.0, -1 + 0.9 * 70], rtol=1e-6)


def test_truncation_bootstraps_termination_does_not():
    ones = torch.ones(2, 21)
    gamma = torch.full((2,), 0.99)
    y_trunc = double_dqn_target(torch.zeros(2), torch.tensor([False, False]), ones, 10 * ones, gamma, torch.zeros(2))
    y_term = double_dqn_target(torch.zeros(2), torch.tensor([True, True]), ones, 10 * ones, gamma, torch.zeros(2))
    np.testing.assert_allclose(y_trunc.numpy(), [9.9, 9.9], rtol=1e-6)
    np.testing.assert_allclose(y_term.numpy(), [0.0, 0.0])


def test_n_step_returns_stop_at_episode_ends():
    rng = np.random.default_rng(4)
    memory = ReplayMemory(200, 8, 1)
    expected, flags = _fill(memory, rng, [6, 4, 30], ["truncated", "terminated", "cut"])
    batch = memory.sample(300, rng, n_step=3, gamma=0.5)
    for b, i in enumerate(batch.indices):
        g, disc, steps = 0.0, 1.0, 0
        for k in range(3):
            if i + k not in flags:  # past the episode's last observation
                break
            g += disc * memory.rewards[i + k]
            disc *= 0.5
            steps += 1
            if any(flags[i + k]):
                break
        assert batch.returns[b] == pytest.approx(g, rel=1e-5)
        assert batch.discounts[b] == pytest.approx(disc)
        assert batch.terminal_rewards[b] == pytest.approx(memory.rewards[i + steps - 1])
        np.testing.assert_array_equal(batch.next_frames[b], expected[i + steps]["frames"])
        ended = [flags[i + k] for k in range(steps)]
        assert bool(batch.terminated[b]) == any(t for t, _ in ended)
        assert bool(batch.truncated[b]) == any(t for _, t in ended)
    assert batch.terminated.any() and batch.truncated.any()


def test_epsilon_schedule():
    assert linear_schedule(1.0, 0.05, 100, 0) == 1.0
    assert linear_schedule(1.0, 0.05, 100, 50) == pytest.approx(0.525)
    assert linear_schedule(1.0, 0.05, 100, 10_000) == 0.05


def test_network_shapes_and_size():
    q = QNetwork()
    out = q(torch.zeros(3, 8, FRAME_H, FRAME_W, dtype=torch.uint8), torch.full((3, 8), 30.0))
    assert out.shape == (3, 21)
    n_params = sum(p.numel() for p in q.parameters())
    assert n_params * 4 < 5e6  # float32 weights under 5 MB
    assert len(FORCES) == 21 and FORCES[0] == -1.0 and FORCES[-1] == 1.0



def _forward_through_the_modules(q: QNetwork, frames, speeds, controls=None):
    """The forward pass as the layer modules compute it, one module call each."""
    parts = [q.conv(frames.float() / 255.0), speeds.float() / q.speed_scale]
    if q.n_controls:
        parts.append((controls.float() / q._control_scale).flatten(1))
    return q.fc(torch.cat(parts, dim=1))


@pytest.mark.parametrize("model", sorted(p.name for p in MODELS_DIR.glob("*.pt")))
def test_the_fast_forward_computes_what_the_layer_modules_compute(model):
    # The forward calls the layers functionally (a third of a decision's time); the
    # shipped models' results, and the reproduction of their training, rest on it giving
    # the module calls' numbers to the last bit, for a decision and for an update.
    q, _ = load_policy(MODELS_DIR / model)
    rng = np.random.default_rng(7)
    for batch in (1, 32):
        frames = torch.from_numpy(rng.integers(0, 256, (batch, 8, FRAME_H, FRAME_W), dtype=np.uint8))
        speeds = torch.from_numpy(rng.uniform(0, 40, (batch, 8)).astype(np.float32))
        controls = torch.from_numpy(rng.uniform(-1, 30, (batch, 8, q.n_controls)).astype(np.float32)) if q.n_controls else None
        with torch.inference_mode():
            assert torch.equal(q(frames, speeds, controls), _forward_through_the_modules(q, frames, speeds, controls))
        grads = []
        for forward in (q.forward, lambda *a: _forward_through_the_modules(q, *a)):
            q.zero_grad()
            forward(frames, speeds, controls).square().sum().backward()
            grads.append([p.grad.clone() for p in q.parameters()])
        assert all(torch.equal(a, b) for a, b in zip(*grads, strict=True))

@pytest.mark.parametrize(("frame_stack", "stride"), [(8, 2), (8, 1), (4, 3), (1, 1)])
def test_the_scaled_frames_are_the_stackers_stack_scaled_to_the_bit(frame_stack, stride):
    # The ddqn controller keeps its frames scaled in rings; the env's stacker stacks them
    # as uint8. Episode starts (the oldest pick repeated), full stacks and resets.
    rng = np.random.default_rng(11)
    stacker, scaled = FrameStacker(frame_stack, stride), ScaledFrames(frame_stack, stride)
    for steps in (3, 40, 17):
        stacker.reset()
        scaled.reset()
        for _ in range(steps):
            frame = rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
            expected = scale_frames(torch.from_numpy(stacker.push(frame, 20.0)["frames"]))
            assert torch.equal(scaled.push(frame), expected)


@pytest.mark.parametrize("model", sorted(p.name for p in MODELS_DIR.glob("*.pt")))
def test_the_controller_and_the_trainer_compute_the_same_outputs(model):
    # The controller feeds the network scaled frames from its rings (views at any offset);
    # the trainer's path feeds uint8 stacks. The same numbers, to the last bit.
    controller = DDQNController.from_checkpoint(MODELS_DIR / model)
    q, cfg = controller.q, controller.cfg
    stacker, rng = FrameStacker(cfg.frame_stack, cfg.stack_stride), np.random.default_rng(12)
    for _ in range(2 * cfg.frame_stack * cfg.stack_stride):
        frame = rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
        controls = np.array([0.1, 30.0], np.float32) if q.n_controls else None
        uint8 = stacker.push(frame, 25.0, controls)
        with torch.inference_mode():
            trainer = q(*batch_of_one(q, uint8["frames"], uint8["speeds"], uint8.get("controls")))
            driver = q(*batch_of_one(q, controller.frames.push(frame), uint8["speeds"], uint8.get("controls")))
        assert torch.equal(trainer, driver)


# -- the network never sees privileged state ----------------------------------------


def test_forward_takes_frames_speeds_and_own_controls_only():
    params = list(inspect.signature(QNetwork.forward).parameters)
    assert params == ["self", "frames", "speeds", "controls"], "the Q-network's input must be frames, host speeds and its controls"
    from agent_client.actions import CONTROLS

    assert CONTROLS == ("force", "set_speed")  # the agent's own last output and the driver's input


class _Recording(dict):
    """A dict that remembers which keys were read."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.read: set[str] = set()

    def __getitem__(self, key):
        self.read.add(key)
        return super().__getitem__(key)

    def get(self, key, default=None):
        self.read.add(key)
        return super().get(key, default)


def _raw_obs(rng: np.random.Generator, gap: float) -> _Recording:
    image = rng.integers(0, 256, (200, 200), dtype=np.uint8)
    return _Recording(
        image=image.tobytes(), image_shape=[200, 200, 1], v_host=29.0, gap=gap, v_lead=31.0,
        a_lead=0.5, accel=0.1, force=0.0, collision=False, t=0.0, frame=0, terminated=False, truncated=False, reason="",
        set_speed=33.5,
    )  # fmt: skip


# held-force types: also the set speed (the driver's input) and the host's own acceleration
# (their anti-windup: the force it achieved), never anything of the lead
HELD = {"image", "image_shape", "v_host", "set_speed", "accel"}


@pytest.mark.parametrize("action, allowed", [("levels", {"image", "image_shape", "v_host"}), ("steps", HELD), ("ramp", HELD), ("ramp-fine", HELD)])
def test_controller_reads_only_image_host_speed_and_set_speed(action, allowed):
    cfg = Config(action=action)
    ctl = DDQNController(QNetwork.of(cfg), cfg)
    obs = _raw_obs(np.random.default_rng(0), gap=40.0)
    ctl(obs)
    assert obs.read <= allowed, f"the ddqn controller read {sorted(obs.read)}"


@pytest.mark.parametrize("action", ACTION_TYPES)
def test_changing_the_gap_cannot_change_the_action(action):
    torch.manual_seed(0)
    cfg = Config(action=action)
    q = QNetwork.of(cfg)
    for layer in q.fc:  # make the output sensitive to its inputs
        if isinstance(layer, torch.nn.Linear):
            torch.nn.init.normal_(layer.weight, std=0.5)
    forces = set()
    for gap in (0.5, 20.0, 55.0, 150.0, 299.0):
        ctl = DDQNController(q, cfg)
        rng = np.random.default_rng(3)  # same frames every time
        forces.add(tuple(ctl(_raw_obs(rng, gap)) for _ in range(10)))
    assert len(forces) == 1


def test_env_observations_carry_no_gap():
    from agent_client.env import VisionACCEnv
    from agent_client.launcher import local_server

    with local_server() as addr:
        env = VisionACCEnv(addr, episode_seconds=1.0)
        try:
            obs, info = env.reset(seed=0)
            assert set(obs) == {"frames", "speeds"}
            assert set(env.observation_space.spaces) == {"frames", "speeds"}
            assert "gap" in info
            assert env.observation_space.contains(obs)
            ctl = DDQNController(QNetwork(), Config(stack_stride=env.stack_stride))
            a = ctl.act(obs)
            info["gap"] = 1.0  # privileged state changes; frames and speeds do not
            assert ctl.act(obs) == a
        finally:
            env.close()


# -- checkpoints ---------------------------------------------------------------------


def test_policy_checkpoint_round_trip(tmp_path):
    q = QNetwork()
    cfg = Config(reward="force", stack_stride=3)
    save_policy(q, cfg, tmp_path / "p.pt", {"step": 7})
    q2, cfg2 = load_policy(tmp_path / "p.pt")
    assert cfg2 == cfg
    x = torch.randint(0, 256, (2, 8, FRAME_H, FRAME_W), dtype=torch.uint8)
    v = torch.rand(2, 8) * 30
    torch.testing.assert_close(q.eval()(x, v), q2(x, v))
    assert (tmp_path / "p.pt").stat().st_size < 5e6
    assert not list(tmp_path.glob("*.tmp"))


@pytest.fixture
def good_checkpoint(tmp_path):
    path = tmp_path / "good.pt"
    save_policy(QNetwork(), Config(), path)
    return path


def test_missing_checkpoint(tmp_path):
    with pytest.raises(InputFileError, match="nope.pt.*not found"):
        load_policy(tmp_path / "nope.pt")


def test_truncated_checkpoint(tmp_path, good_checkpoint):
    bad = tmp_path / "cut.pt"
    bad.write_bytes(good_checkpoint.read_bytes()[: good_checkpoint.stat().st_size // 2])
    with pytest.raises(InputFileError, match="cut.pt.*truncated or corrupt"):
        load_policy(bad)


def test_garbage_checkpoint(tmp_path):
    bad = tmp_path / "junk.pt"
    bad.write_bytes(b"this is not a checkpoint\n" * 10)
    with pytest.raises(InputFileError, match="junk.pt"):
        load_policy(bad)


def test_foreign_checkpoint(tmp_path):
    bad = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, bad)
    with pytest.raises(InputFileError, match="foreign.pt.*not a vacc DDQN checkpoint"):
        load_policy(bad)


def test_wrong_version_checkpoint(tmp_path, good_checkpoint):
    ckpt = torch.load(good_checkpoint, weights_only=True)
    ckpt["version"] = CHECKPOINT_VERSION + 1
    bad = tmp_path / "future.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputFileError, match="future.pt.*version"):
        load_policy(bad)


def test_wrong_shape_checkpoint(tmp_path, good_checkpoint):
    ckpt = torch.load(good_checkpoint, weights_only=True)
    assert ckpt["format"] == CHECKPOINT_FORMAT
    ckpt["model"]["fc.2.weight"] = torch.zeros(5, 256)  # 5 actions instead of 21
    ckpt["sha256"] = digest(ckpt)  # a consistent file, written with the wrong network
    bad = tmp_path / "shape.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputFileError, match="shape.pt.*do not fit"):
        load_policy(bad)
    del ckpt["model"]["fc.2.weight"]
    ckpt["sha256"] = digest(ckpt)
    torch.save(ckpt, bad)
    with pytest.raises(InputFileError, match="shape.pt"):
        load_policy(bad)


def test_flipped_bytes_in_a_checkpoint_fail_in_one_line_naming_the_file(tmp_path, good_checkpoint):
    ckpt = torch.load(good_checkpoint, weights_only=True)
    ckpt["model"]["conv.0.weight"].view(-1)[:16] = 839.0  # what 64 flipped bytes once did, silently
    bad = tmp_path / "flipped.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputFileError, match=r"flipped.pt: checkpoint is corrupt \(its SHA-256") as info:
        load_policy(bad)
    assert "\n" not in str(info.value)
    raw = bytearray(good_checkpoint.read_bytes())  # bytes flipped inside the file itself
    middle = len(raw) // 2
    raw[middle : middle + 64] = bytes(b ^ 0xFF for b in raw[middle : middle + 64])
    bad.write_bytes(bytes(raw))
    with pytest.raises(InputFileError, match="flipped.pt") as info:
        load_policy(bad)
    assert "\n" not in str(info.value)


def test_the_shipped_models_load_and_carry_a_digest():
    for path in sorted(MODELS_DIR.glob("*.pt")):
        q, cfg = load_policy(path)
        ckpt = torch.load(path, weights_only=True)
        assert ckpt["version"] == CHECKPOINT_VERSION and ckpt["sha256"] == digest(ckpt), path
        assert path.stat().st_size <= 5 * 1024 * 1024


def test_a_full_disk_leaves_no_temporary_file_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    path = tmp_path / "best.pt"
    save_policy(QNetwork(), Config(), path)
    before = path.read_bytes()

    def full(obj, f, *args, **kwargs):
        raise OSError(28, "No space left on device")  # ENOSPC, as torch.save meets it

    def short_write(obj, f, *args, **kwargs):  # what torch.save raises on a full disk
        Path(f).write_bytes(b"PK\x03\x04 part of a file")
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 1024 vs 512")

    for fail in (full, short_write):
        monkeypatch.setattr(torch, "save", fail)
        with pytest.raises(CheckpointWriteError, match="best.pt: could not be written: no space left on device") as info:
            save_policy(QNetwork(), Config(), path)
        assert "\n" not in str(info.value) and "inline_container" not in str(info.value)
        assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["best.pt"]
        load_policy(path)


@pytest.fixture
def after_a_first_ctrl_c():
    """The CLI's signal handlers installed and STOP set, as after a first Ctrl-C."""
    from agent_client.rl.stop import STOP, stop_handlers

    with stop_handlers("vacc train", ""):
        STOP.set()
        yield


def _ctrl_c_mid_write(path) -> None:
    """Half a file, then the second Ctrl-C: the handler raises SystemExit here."""
    Path(path).write_bytes(b"PK\x03\x04 half a file")
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)


def test_a_second_ctrl_c_during_a_write_leaves_no_temporary_file(tmp_path, after_a_first_ctrl_c):
    path = tmp_path / "best.pt"
    save_policy(QNetwork(), Config(), path)
    before = path.read_bytes()
    with pytest.raises(SystemExit) as info:
        write_atomically(path, _ctrl_c_mid_write)
    assert info.value.code == 130
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["best.pt"]


@pytest.mark.parametrize("failure", ["full disk", "second Ctrl-C"])
def test_a_failed_checkpoint_removes_the_replay_it_wrote_and_the_last_one_resumes(tmp_path, monkeypatch, after_a_first_ctrl_c, failure):
    from agent_client.rl.learner import Learner

    cfg = Config(buffer_size=100, eval_trajectories=(), schedule="serial")
    learner = Learner(cfg, tmp_path)
    memory = ReplayMemory(cfg.buffer_size, cfg.frame_stack, cfg.stack_stride)
    rng = np.random.default_rng(0)
    _fill(memory, rng, [10], ["cut"])
    learner.checkpoint({"global_step": 10}, memory)
    _fill(memory, rng, [10], ["cut"])

    def full(obj, f, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", full if failure == "full disk" else lambda obj, f, *a, **k: _ctrl_c_mid_write(f))
    with pytest.raises(CheckpointWriteError if failure == "full disk" else SystemExit):
        learner.checkpoint({"global_step": 20}, memory)
    monkeypatch.undo()
    learner.close()
    assert not list(tmp_path.glob("*.tmp")) and [p.name for p in tmp_path.glob("replay-*")] == ["replay-10.npz"]
    resumed = Learner(cfg, tmp_path, resume=True)
    resumed.close()
    assert resumed.saved["global_step"] == 10 and resumed.replay_names == ["replay-10.npz"]
    assert ReplayMemory(cfg.buffer_size, cfg.frame_stack, cfg.stack_stride).load(tmp_path / "replay-10.npz") == 10


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="reward"):
        Config(reward="speed")
    with pytest.raises(ValueError, match="--preroll needs the single-stream trainer"):
        Config(preroll=True, servers=2)
    with pytest.raises(ValueError, match="scenario"):
        Config(scenario="moon")
    with pytest.raises(ValueError, match=r"crash_reward must be in \[-10, 0\], got 0.5"):
        Config(crash_reward=0.5)


def test_tensorboard_gets_the_config_and_the_first_frames(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from agent_client.rl.scalars import ScalarLog

    log = ScalarLog(tmp_path)
    log.text("config", "```\n{}\n```")
    log.frames("charts/first_observation", np.zeros((8, FRAME_H, FRAME_W), np.uint8), 0)
    log.close()
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    assert events.Tags()["images"] == ["charts/first_observation"] and "config/text_summary" in events.Tags()["tensors"]


def test_a_garbage_scalars_csv_fails_a_resume_in_one_line(tmp_path):
    from agent_client.rl.scalars import ScalarLog

    (tmp_path / "scalars.csv").write_text("step,name,value,wall_s\n5,charts/x,1,0.1\n\x00\x01garbage\n")
    with pytest.raises(InputFileError, match=r"scalars.csv:3: not a step,name,value,wall_s row") as info:
        ScalarLog(tmp_path, resume_step=10)
    assert "\n" not in str(info.value)


def test_the_logged_wall_time_sums_the_segments_of_a_resumed_run(tmp_path):
    from agent_client.rl.scalars import logged_wall_s

    # 100 s, then resumed at step 20 (the clock starts again) for 40 s more, then 7 s more
    rows = "5,charts/x,1,60.0\n20,charts/x,1,100.0\n30,charts/x,1,15.0\n40,charts/x,1,40.0\n50,charts/x,1,7.0\n"
    (tmp_path / "scalars.csv").write_text("step,name,value,wall_s\n" + rows)
    assert logged_wall_s(tmp_path) == pytest.approx(147.0)
    (tmp_path / "scalars.csv").write_text("step,name,value,wall_s\n")
    assert logged_wall_s(tmp_path) == 0.0
    with pytest.raises(InputFileError, match="not found"):
        logged_wall_s(tmp_path / "none")


def test_a_row_torn_by_a_kill_is_dropped_on_resume_and_rows_reach_the_disk_while_training(tmp_path, monkeypatch):
    """A kill -9 while the writer's buffer reaches the disk can leave half a row at the end;
    a resume drops it (it was never whole) instead of refusing the run."""
    from agent_client.rl import scalars
    from agent_client.rl.scalars import ScalarLog

    (tmp_path / "scalars.csv").write_text("step,name,value,wall_s\n5,charts/x,1,0.1\n12,charts/x,2,0.2\n13,char")
    log = ScalarLog(tmp_path, resume_step=12)
    log.close()
    assert (tmp_path / "scalars.csv").read_text() == "step,name,value,wall_s\n5,charts/x,1,0.1\n12,charts/x,2,0.2\n"
    monkeypatch.setattr(scalars, "FLUSH_EVERY_S", 0.0)  # every row: a user tailing the file sees it
    log = ScalarLog(tmp_path)
    log.add("charts/x", 3.0, 14)
    assert "14,charts/x,3" in (tmp_path / "scalars.csv").read_text()
    log.close()


def test_every_config_field_is_in_one_section_and_each_section_checks_itself():
    from agent_client.rl.config import SECTIONS, SETTINGS, ConfigError, DQNSettings, TeacherSettings

    names = [name for fields in SECTIONS.values() for name in fields]
    assert sorted(names) == sorted(f.name for f in dataclasses.fields(Config))  # each in exactly one
    assert all(issubclass(Config, kind) for kind in SETTINGS.values())
    # a section alone refuses its own bad values, and Config hands each section its fields
    with pytest.raises(ConfigError, match="gamma must be in"):
        DQNSettings(gamma=1.0)
    with pytest.raises(ConfigError, match="teacher_policy is the checkpoint"):
        TeacherSettings(teacher_policy="x.pt")
    cfg = Config(gamma=0.9, teacher_steps=7)
    assert cfg.section(DQNSettings) == DQNSettings(gamma=0.9)
    assert cfg.section(TeacherSettings).teacher_steps == 7


@pytest.mark.parametrize("bad", [
    {"set_speed": 99.0}, {"train_traffic": -1}, {"gamma": 1.0}, {"batch_size": 0}, {"hidden": 0}, {"zoom": 3},
    {"eval_trajectories": ("nowhere",)}, {"teacher_lag": -1.0}, {"aux_closing": float("nan")},
    {"decision_smoothing": 0.0}, {"actor_batch": 0}, {"teacher_policy": "x.pt"},
])  # fmt: skip
def test_a_bad_setting_fails_naming_its_field(bad):
    from agent_client.rl.config import ConfigError

    (name,) = bad
    with pytest.raises(ConfigError) as info:
        Config(**bad)
    assert info.value.field == name


def test_stop_handlers_restore_what_was_there_and_clear_the_stop():
    """A CLI run in-process (CliRunner) leaves the test process's signals as they were."""
    from agent_client.rl.stop import STOP, stop_exit_code, stop_handlers

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with stop_handlers("vacc train", ""):
        assert signal.getsignal(signal.SIGTERM) not in before
        signal.raise_signal(signal.SIGTERM)  # the first: sets STOP, raises nothing
        assert STOP.is_set() and stop_exit_code() == 143
        with pytest.raises(SystemExit) as info:
            signal.raise_signal(signal.SIGINT)  # the second aborts
        assert info.value.code == 130
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert not STOP.is_set() and stop_exit_code() == 130
