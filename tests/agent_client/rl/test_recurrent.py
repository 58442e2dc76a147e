"""The recurrent trunk (--recurrent gru): a GRU state carried step to step, replayed
sequences with stored states and burn-in (R2D2), training and resuming over real servers."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from agent_client.rl import actor_critic as ac
from agent_client.rl.checkpoint import load_policy, save_policy
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.network import Policy, QNetwork, RecurrentQNetwork, transfer_weights
from agent_client.rl.replay import ReplayMemory
from agent_client.rl.train import train
from vacc.cli import main

H, W = 105, 150
GRU = dict(recurrent="gru", frame_stack=2, stack_stride=1, burn_in=3, sequence_length=6)
TINY = Config(
    total_steps=120, learning_starts=30, train_every=4, batch_size=4, buffer_size=400, exploration_steps=100, target_sync_every=40,
    episode_seconds=3.0, checkpoint_every=30, eval_every=0, eval_trajectories=(), log_every=20, hidden=32, conv_channels=(4, 8, 8), **GRU,
)  # fmt: skip


def _net(seed: int = 0) -> RecurrentQNetwork:
    torch.manual_seed(seed)
    net = QNetwork.of(TINY)
    assert isinstance(net, RecurrentQNetwork)
    return net.eval()


def _obs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {"frames": rng.integers(0, 256, (2, H, W), dtype=np.uint8), "speeds": rng.uniform(0, 30, 2).astype(np.float32)}


def test_stepping_equals_unrolling_and_the_state_starts_at_zero():
    net, rng = _net(), np.random.default_rng(0)
    seq = [_obs(rng) for _ in range(5)]
    frames = torch.from_numpy(np.stack([o["frames"] for o in seq]))[None]
    speeds = torch.from_numpy(np.stack([o["speeds"] for o in seq]))[None]
    with torch.no_grad():
        unrolled, *_ , last = net.unroll(frames, speeds, None, net.initial_state(1))
        h = net.initial_state(1)
        for k in range(5):
            q, _, _, h = net.step(frames[:, k], speeds[:, k], None, h)
            torch.testing.assert_close(q, unrolled[:, k], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(h, last, rtol=1e-5, atol=1e-6)
    with pytest.raises(TypeError, match="state"):
        net(frames[:, 0], speeds[:, 0])  # no silent decision without the state


def test_a_policy_carries_the_state_and_forgets_it_with_the_episode():
    net, rng = _net(), np.random.default_rng(1)
    policy = Policy(net)
    history, probe = [_obs(rng) for _ in range(4)], _obs(rng)
    assert not policy.state().any()
    cold = policy.outputs(probe["frames"], probe["speeds"])[0]
    policy.reset()
    for o in history:
        policy(o)
    assert policy.state().any()
    warm = policy.outputs(probe["frames"], probe["speeds"])[0]
    assert not torch.equal(cold, warm)  # what came before changes the answer
    policy.reset()
    assert not policy.state().any()
    assert torch.equal(policy.outputs(probe["frames"], probe["speeds"])[0], cold)  # to the bit
    assert Policy(QNetwork(2, hidden=32, conv_channels=(4, 8, 8))).state() is None


def _memory_with_two_episodes() -> tuple[ReplayMemory, list[int]]:
    """Episode A: 10 transitions (slots 0..10, truncated); episode B: 5 transitions (11..16, terminated).
    Each slot's frame is its slot number; its state is the slot number in every unit."""
    mem = ReplayMemory(100, frame_stack=2, stack_stride=1, state_size=3)

    def obs(slot: int) -> dict[str, np.ndarray]:
        return {"frames": np.full((2, H, W), slot, np.uint8), "speeds": np.full(2, slot, np.float32)}

    slot = 0
    for n, end in ((10, "truncated"), (5, "terminated")):
        mem.start(obs(slot), state=np.full(3, slot, np.float32))
        for k in range(n):
            slot += 1
            last = k == n - 1
            mem.add(k % 3, float(slot), last and end == "terminated", last and end == "truncated", obs(slot), state=np.full(3, slot, np.float32))
        slot += 1
    return mem, [0, 11]


def test_sequences_keep_their_stored_state_and_stop_at_the_episodes_end():
    mem, starts = _memory_with_two_episodes()
    seq = mem.sample_sequences(64, np.random.default_rng(0), length=6, burn_in=3)
    for b, i in enumerate(seq.indices):
        i = int(i)
        assert seq.states[b].tolist() == [float(i)] * 3
        episode_end = 10 if i < 11 else 16  # the slot of the episode's last observation
        n = min(6, episode_end - i)
        assert seq.mask[b].tolist() == [k < n for k in range(6)]
        # step k's newest frame is slot i + k; past the end the last observation repeats
        assert seq.frames[b, :, -1, 0, 0].tolist() == [min(i + k, episode_end) for k in range(7)]
        assert seq.rewards[b, :n].tolist() == [float(i + k + 1) for k in range(n)]
        assert bool(seq.terminated[b].any()) == (i >= 11 and i + 6 >= 16)
        # an episode's first observation has an exact state: every step trains; else only past the burn-in
        first = i in starts
        assert seq.train[b].tolist() == [k < n and (first or k >= 3) for k in range(6)]
    assert {int(i) for i in seq.indices} & set(starts)  # both kinds were drawn


def test_a_memory_without_states_has_no_sequences_and_one_with_them_needs_them():
    with pytest.raises(ValueError, match="state_size"):
        ReplayMemory(10, 2, 1).sample_sequences(1, np.random.default_rng(0), 4, 1)
    with pytest.raises(ValueError, match="recurrent state"):
        ReplayMemory(10, 2, 1, state_size=3).start({"frames": np.zeros((2, H, W), np.uint8), "speeds": np.zeros(2, np.float32)})


@pytest.mark.parametrize(("change", "field"), [
    (dict(n_step=3), "n_step"), (dict(servers=2), "recurrent"),
    (dict(sequence_length=3), "sequence_length"), (dict(recurrent="lstm"), "recurrent"),
])  # fmt: skip
def test_what_the_recurrent_trunk_does_not_do_is_refused_by_name(change, field):
    with pytest.raises(ConfigError) as err:
        dataclasses.replace(TINY, **change)
    assert err.value.field == field


@pytest.mark.integration
def test_a_recurrent_run_resumed_equals_an_uninterrupted_one_and_drives(tmp_path):
    cfg = dataclasses.replace(TINY, teacher="platoon", action="ramp-fine", decision="mean", aux_closing=0.1, preroll=True,
                              train_trajectories=("stopped", "random"))  # fmt: skip
    whole = train(cfg, tmp_path / "whole", progress=False)
    train(dataclasses.replace(cfg, total_steps=60), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = (torch.load(tmp_path / d / "latest.pt", weights_only=True) for d in ("whole", "split"))
    assert whole["steps"] == 120 and a["state"]["episodes"] == b["state"]["episodes"] > 1 and a["state"]["updates"] > 0
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    assert any(k.startswith("gru.") for k in a["model"])
    # the memory kept a state with every observation, and the states moved
    with np.load(tmp_path / "whole" / a["replay"][0]) as z:
        assert z["states"].shape[1] == 32 and z["states"].shape[0] > whole["steps"] and np.abs(z["states"]).sum() > 0
    net, loaded = load_policy(str(tmp_path / "whole" / "latest.pt"))
    assert isinstance(net, RecurrentQNetwork) and loaded.recurrent == "gru"


def test_a_recurrent_policy_saves_loads_and_refuses_to_be_narrowed(tmp_path):
    from agent_client.errors import InputFileError
    from agent_client.rl.checkpoint import narrow_policy

    net = _net(3)
    save_policy(net, TINY, tmp_path / "gru.pt")
    loaded, cfg = load_policy(str(tmp_path / "gru.pt"))
    assert isinstance(loaded, RecurrentQNetwork) and cfg.burn_in == 3
    for name, t in net.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], t), name
    with pytest.raises(InputFileError, match="recurrent policy .* cannot be narrowed"):
        narrow_policy(tmp_path / "gru.pt", tmp_path / "narrow.pt", (2, 4, 4), 16)


# ------------------------------------------------------------- the actor-critic's GRU

AC = dataclasses.replace(TINY, action="continuous", total_steps=100, batch_size=4, n_step=1)


def _ac(seed: int = 0) -> ac.RecurrentActorCritic:
    torch.manual_seed(seed)
    net = ac.network_of(AC)
    assert isinstance(net, ac.RecurrentActorCritic)
    return net.eval()


def _ac_obs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {**_obs(rng), "controls": rng.uniform(-1, 1, (2, 2)).astype(np.float32)}


def test_the_recurrent_actor_steps_as_it_unrolls_and_its_policy_forgets_with_the_episode():
    net, rng = _ac(), np.random.default_rng(4)
    seq = [_ac_obs(rng) for _ in range(5)]
    frames, speeds, controls = (torch.from_numpy(np.stack([o[k] for o in seq]))[None] for k in ("frames", "speeds", "controls"))
    with torch.no_grad():
        h_all = net.unroll(frames, speeds, controls, net.initial_state(1))  # [1, 5, H]
        h = net.initial_state(1)
        for k in range(5):
            a, h = net.step(frames[:, k], speeds[:, k], controls[:, k], h)
            torch.testing.assert_close(h, h_all[:, k], rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(a, net.actor(h_all[:, k]), rtol=1e-5, atol=1e-6)
    with pytest.raises(TypeError, match="state"):
        net(frames[:, 0], speeds[:, 0], controls[:, 0])
    policy = ac.policy_of(net, AC)
    cold = policy(seq[-1]).continuous
    assert policy.state().any() and policy.fresh() is not policy and not policy.fresh().state().any()
    policy.reset()
    for o in seq[:-1]:
        policy(o)
    assert policy(seq[-1]).continuous != cold  # what came before changes the answer
    policy.reset()
    assert not policy.state().any() and policy(seq[-1]).continuous == cold  # to the bit
    from agent_client.bench.ddqn import decision_latency  # vacc bench times it as any policy

    assert decision_latency(net, repeats=3, cfg=AC)["forward_median_s"] > 0


def test_a_sequence_update_trains_trunk_gru_actor_and_critic_and_moves_only_the_critics_target():
    rng = np.random.default_rng(5)
    mem = ReplayMemory(200, 2, 1, n_controls=2, continuous=True, state_size=32)
    mem.start(_ac_obs(rng), state=np.zeros(32, np.float32))
    for i in range(60):
        mem.add(float(np.float32(rng.uniform(-1, 1))), float(rng.normal()), False, i % 20 == 19, _ac_obs(rng), state=rng.normal(size=32).astype(np.float32))
        if i % 20 == 19:
            mem.start(_ac_obs(rng), state=np.zeros(32, np.float32))
    seq = mem.sample_sequences(4, rng, 6, 3)
    assert seq.actions.dtype == torch.float32  # target forces, not rounded to levels
    net = _ac(1).train()
    target = ac.target_of(net)
    before, target_before = ({k: v.clone() for k, v in m.state_dict().items()} for m in (net, target))
    losses = ac.update_sequences(net, target, torch.optim.Adam(net.parameters(), 1e-3), seq, AC, 0.2, torch.device("cpu"), True)
    assert losses is not None and np.isfinite(losses.critic) and np.isfinite(losses.actor)
    moved = {k for k, v in net.state_dict().items() if not torch.equal(v, before[k])}
    assert {"conv.0.weight", "encoder.0.weight", "gru.weight_hh_l0", "fc.0.weight", "critic_trunk.0.weight", "q1.0.weight"} <= moved
    target_moved = {k.split(".")[0] for k, v in target.state_dict().items() if not torch.equal(v, target_before[k])}
    assert target_moved == {"critic_trunk", "q1", "q2"}


def test_on_a_sequence_the_actors_loss_reaches_the_actor_alone_and_the_critics_the_trunk_and_gru():
    rng = np.random.default_rng(6)
    net = _ac(2).train()
    frames = torch.from_numpy(rng.integers(0, 256, (3, 5, 2, H, W), dtype=np.uint8)).float() / 255.0
    speeds, controls = torch.rand(3, 5, 2) * 30, torch.rand(3, 5, 2, 2)
    keep = torch.ones(3, 4, dtype=torch.bool)
    keep[0, :2] = False  # a burn-in
    z = net.unroll(frames, speeds, controls, torch.randn(3, 32))[:, :-1][keep]  # [N, H]
    frozen = {k: v.detach() for k, v in net.named_parameters() if k.startswith(("critic_trunk", "q1", "q2"))}
    (-torch.min(*ac._critic_with(net, frozen, z.detach(), net.actor(z.detach()))).mean()).backward(retain_graph=True)
    assert {k for k, p in net.named_parameters() if p.grad is not None} == {"fc.0.weight", "fc.0.bias", "fc.2.weight", "fc.2.bias"}
    net.zero_grad(set_to_none=True)
    q1, q2 = net.critic(z, torch.zeros(len(z)))
    (q1.pow(2).mean() + q2.pow(2).mean()).backward()
    reached = {k.split(".")[0] for k, p in net.named_parameters() if p.grad is not None}
    assert reached == {"conv", "encoder", "gru", "critic_trunk", "q1", "q2"}


def test_the_recurrent_actor_starts_from_a_dqns_trunk_its_hidden_layer_as_its_encoder():
    torch.manual_seed(7)
    dqn = QNetwork.of(dataclasses.replace(TINY, recurrent="none", action="ramp-fine"))
    net = _ac(8)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    start = ac.recurrent_start(dqn)
    assert set(start) == {k for k in dqn.state_dict() if k.startswith("conv.")} | {"encoder.0.weight", "encoder.0.bias"}
    transfer_weights(start, net)
    after = net.state_dict()
    assert torch.equal(after["encoder.0.weight"], dqn.state_dict()["fc.0.weight"]) and torch.equal(after["conv.0.weight"], dqn.state_dict()["conv.0.weight"])
    assert all(torch.equal(after[k], before[k]) for k in after if k.startswith(("fc.", "critic_trunk", "q1", "q2", "gru")))  # afresh
    # a recurrent DQN gives its GRU too; a frame-stack actor-critic only its convolutions
    assert any(k.startswith("gru.") for k in ac.recurrent_start(_net(9)))
    assert all(k.startswith("conv.") for k in ac.recurrent_start(ac.network_of(dataclasses.replace(AC, recurrent="none"))))


@pytest.mark.integration
def test_a_recurrent_actor_critic_cloned_from_a_student_resumes_bit_exact_and_drives(tmp_path):
    student_cfg = Config(action="ramp-fine", frame_stack=2, stack_stride=1, conv_channels=(4, 8, 8), hidden=32)
    torch.manual_seed(3)
    save_policy(QNetwork.of(student_cfg), student_cfg, tmp_path / "student.pt")
    cfg = dataclasses.replace(AC, init_from=str(tmp_path / "student.pt"), bc_steps=10, train_trajectories=("stopped", "random"))
    whole = train(cfg, tmp_path / "whole", progress=False)
    train(dataclasses.replace(cfg, total_steps=60), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = (torch.load(tmp_path / d / "latest.pt", weights_only=True) for d in ("whole", "split"))
    assert whole["steps"] == 100 and a["state"]["updates"] > 0 and any(k.startswith("gru.") for k in a["model"])
    for part in ("model", "target"):
        for key in a[part]:
            torch.testing.assert_close(a[part][key], b[part][key], rtol=0, atol=0)
    with np.load(tmp_path / "whole" / a["replay"][0]) as z:
        assert z["states"].shape[1] == 32 and np.abs(z["states"]).sum() > 0
    net, loaded = load_policy(str(tmp_path / "whole" / "latest.pt"))
    assert isinstance(net, ac.RecurrentActorCritic) and loaded.recurrent == "gru"
    log = tmp_path / "drive.csv"  # vacc drive: the recurrent actor drives, its forces ramped
    result = CliRunner().invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(tmp_path / "whole" / "latest.pt"),
                                       "--trajectory", "test-1", "--duration", "3", "--log", str(log), "--quiet"])  # fmt: skip
    assert result.exit_code == 0, result.output
    forces = [float(r["force"]) for r in csv.DictReader(open(log)) if r.get("force")]
    assert len(forces) > 20 and len(set(forces)) > 1
    # a recurrent network is no student to clone: refused before anything runs
    from agent_client.errors import InputFileError

    with pytest.raises(InputFileError, match="recurrent network cannot be the student of --bc-steps"):
        train(dataclasses.replace(cfg, init_from=str(tmp_path / "whole" / "latest.pt")), tmp_path / "again", progress=False)
