"""The actor-critic (DrQ-v2) for the continuous action: its pieces, then tiny runs over real servers."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from agent_client.rl import actor_critic as ac
from agent_client.rl.checkpoint import load_policy, save_policy
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.network import QNetwork, transfer_weights
from agent_client.rl.replay import ReplayMemory
from agent_client.rl.train import train
from vacc.cli import main

CONT = Config(
    action="continuous", total_steps=100, learning_starts=30, train_every=4, batch_size=8, buffer_size=400,
    exploration_steps=100, episode_seconds=3.0, checkpoint_every=30, eval_every=0, eval_trajectories=(), log_every=20,
    conv_channels=(4, 8, 8), hidden=32,
)  # fmt: skip
S, H, W = 8, 105, 150


def _batch(memory_actions: str = "continuous", n: int = 60, seed: int = 0):
    rng = np.random.default_rng(seed)
    m = ReplayMemory(200, S, 2, n_controls=2, continuous=memory_actions == "continuous")
    obs = lambda: {"frames": rng.integers(0, 255, (S, H, W), np.uint8), "speeds": rng.uniform(0, 30, S).astype(np.float32),  # noqa: E731
                   "controls": rng.uniform(-1, 1, (S, 2)).astype(np.float32)}  # fmt: skip
    m.start(obs())
    for i in range(n):
        m.add(float(np.float32(rng.uniform(-1, 1))), float(rng.normal()), False, i % 20 == 19, obs())
        if i % 20 == 19:
            m.start(obs())
    return m


def test_random_shift_moves_each_stack_as_one_and_pad_zero_is_the_identity():
    torch.manual_seed(0)
    x = torch.rand(4, S, H, W)
    assert ac.random_shift(x, 0) is x
    y = ac.random_shift(x, 4)
    assert y.shape == x.shape
    for i in range(4):  # some shift (dy, dx) in [-4, 4]^2 explains every frame of stack i
        pad = torch.nn.functional.pad(x[i : i + 1], (4, 4, 4, 4), mode="replicate")[0]
        assert any(torch.equal(pad[:, dy : dy + H, dx : dx + W], y[i]) for dy in range(9) for dx in range(9))


def test_replay_stores_float_actions_and_keeps_the_discrete_memory_as_it_was(tmp_path):
    m = _batch()
    assert m.actions.dtype == np.float32
    b = m.sample(8, np.random.default_rng(1), 3, 0.99)
    assert b.actions.dtype == torch.float32 and (b.actions.abs() <= 1).all()
    m.save(tmp_path / "r.npz", 7)
    again = ReplayMemory(200, S, 2, n_controls=2, continuous=True)
    assert again.load(tmp_path / "r.npz") == 7 and np.array_equal(again.actions, m.actions)
    d = ReplayMemory(10, S, 2)
    assert d.actions.dtype == np.uint8  # the DQN's memories and files as ever


def test_update_trains_the_critic_through_the_trunk_and_the_actor_alone():
    torch.manual_seed(0)
    net = ac.ActorCritic.of(CONT)
    target = ac.target_of(net)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    b = _batch().sample(8, np.random.default_rng(1), 3, 0.99)
    losses = ac.update(net, target, opt, b, CONT, 0.2, torch.device("cpu"), log=True)
    assert losses is not None and np.isfinite(losses[:3]).all() and losses.bc is None  # no anchor: DrQ-v2's actor loss
    moved = {k for k, v in net.state_dict().items() if not torch.equal(v, before[k])}
    assert {"conv.0.weight", "fc.0.weight", "fc.2.weight", "critic_trunk.0.weight", "q1.0.weight", "q2.2.weight"} <= moved
    # the target moved critic_tau of the way, and only its critic
    t_moved = {k for k, v in target.state_dict().items() if not torch.equal(v, before[k])}
    assert t_moved and all(k.startswith(("critic_trunk", "q1", "q2")) for k in t_moved)


def _three_updates(net: ac.ActorCritic, cfg: Config, actor: bool = True):
    """Three updates of ``net`` on one replay batch: the names of the tensors they moved, and
    what a further update needs (the batch, the critic's target, the optimiser, the weights before)."""
    target = ac.target_of(net)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    b = _batch().sample(8, np.random.default_rng(1), 3, 0.99)
    for _ in range(3):
        ac.update(net, target, opt, b, cfg, 0.2, torch.device("cpu"), log=False, actor=actor)
    moved = {k for k, v in net.state_dict().items() if not torch.equal(v, before[k])}
    return moved, b, target, opt, before


def test_in_the_critics_warmup_the_actor_and_its_trunk_do_not_move_and_the_critic_does():
    torch.manual_seed(0)
    net = ac.ActorCritic.of(CONT)
    moved, b, target, opt, before = _three_updates(net, CONT, actor=False)
    assert {"critic_trunk.0.weight", "q1.0.weight", "q2.2.weight"} <= moved  # the critic's own layers
    assert not moved & {"conv.0.weight", "conv.4.weight", "fc.0.weight", "fc.2.weight", "fc.2.bias"}  # what the actor reads, and the actor
    ac.update(net, target, opt, b, CONT, 0.2, torch.device("cpu"), log=False)  # after it: the actor learns
    assert not torch.equal(net.state_dict()["fc.2.weight"], before["fc.2.weight"])


def test_a_frozen_trunk_stays_while_the_actor_and_the_critics_own_layers_learn():
    torch.manual_seed(0)
    cfg = Config(**{**CONT.__dict__, "trunk_training": "frozen", "init_from": "student.pt"})
    moved = _three_updates(ac.ActorCritic.of(cfg), cfg)[0]
    assert {"fc.0.weight", "fc.2.weight", "critic_trunk.0.weight", "q1.0.weight", "q2.2.weight"} <= moved
    assert not any(k.startswith("conv.") for k in moved)  # the features the actor reads do not move under it


def test_a_critics_copy_of_the_trunk_learns_and_the_actors_stays():
    torch.manual_seed(0)
    cfg = Config(**{**CONT.__dict__, "trunk_training": "critic-copy", "init_from": "student.pt"})
    net = ac.ActorCritic.of(cfg)
    net.critic_conv.load_state_dict(net.conv.state_dict())  # as init_from starts it
    moved, b = _three_updates(net, cfg)[:2]
    assert {"critic_conv.0.weight", "critic_conv.4.weight", "fc.2.weight", "q1.0.weight"} <= moved
    assert not any(k.startswith("conv.") for k in moved)
    decision = net(b.frames, b.speeds, b.controls)
    with torch.no_grad():
        net.critic_conv[0].weight.mul_(-1.0)
    assert torch.equal(net(b.frames, b.speeds, b.controls), decision)  # a decision reads the actor's trunk alone: one pass, as fast


def test_the_actors_loss_reaches_the_actor_only():
    torch.manual_seed(0)
    net = ac.ActorCritic.of(CONT)
    b = _batch().sample(8, np.random.default_rng(1), 1, 0.99)
    z = net.features(b.frames, b.speeds, b.controls).detach()
    frozen = {k: v.detach() for k, v in net.named_parameters() if k.startswith(("critic_trunk", "q1", "q2"))}
    q1, q2 = ac._critic_with(net, frozen, z, net.actor(z))
    torch.testing.assert_close(q1, net.critic(z, net.actor(z))[0])  # the critic's own numbers
    (-torch.min(q1, q2).mean()).backward()
    assert {k for k, p in net.named_parameters() if p.grad is not None} == {"fc.0.weight", "fc.0.bias", "fc.2.weight", "fc.2.bias"}


def test_decision_is_one_pass_of_the_dqn_sized_trunk_rounded_as_the_env_applies_it():
    net = ac.ActorCritic.of(Config(action="continuous")).eval()
    dqn = QNetwork.of(Config(action="ramp-fine"))
    shared = [k for k in net.state_dict() if k.startswith("conv.") or k == "fc.0.weight"]
    assert all(net.state_dict()[k].shape == dqn.state_dict()[k].shape for k in shared)  # the same trunk
    obs = {"frames": np.zeros((S, H, W), np.uint8), "speeds": np.full(S, 20.0, np.float32), "controls": np.zeros((S, 2), np.float32)}
    d = ac.ActorPolicy(net)(obs)
    assert d.continuous is not None and d.continuous == float(np.float32(d.continuous)) and -1.0 < d.continuous < 1.0


def test_student_targets_follow_its_decision_rule():
    torch.manual_seed(0)
    q = QNetwork.of(Config(action="ramp-fine", conv_channels=(4, 8, 8), hidden=32))
    b = _batch().sample(8, np.random.default_rng(1), 1, 0.99)
    out = q(b.frames, b.speeds, b.controls)
    from agent_client.actions import FINE_LEVELS

    argmax = ac.student_targets(q, Config(action="ramp-fine"), b.frames, b.speeds, b.controls)
    assert argmax.tolist() == pytest.approx([FINE_LEVELS[a] for a in out.argmax(1).tolist()])
    with torch.no_grad():  # the full brake the argmax: -1
        q.fc[-1].bias[0] = 1e3
    assert (ac.student_targets(q, Config(action="ramp-fine"), b.frames, b.speeds, b.controls) == -1.0).all()
    with torch.no_grad():
        q.fc[-1].bias[0] = -1e3
    mean_cfg = Config(action="ramp-fine", teacher="acc", decision="mean")
    mean = ac.student_targets(q, mean_cfg, b.frames, b.speeds, b.controls)
    assert ((mean > -1.0) & (mean < 1.0)).all() and not torch.equal(mean, argmax)


def test_behaviour_cloning_learns_the_students_decision_on_a_tiny_set():
    torch.manual_seed(0)
    cfg = Config(action="ramp-fine", conv_channels=(4, 8, 8), hidden=32)
    student = QNetwork.of(cfg)
    net = ac.ActorCritic.of(CONT)
    kept = transfer_weights(student, net)  # the trunk copies; the actor's output and the critic are new
    assert "conv.0.weight" not in kept and "fc.2.weight" in kept and "q1.0.weight" in kept
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    b = _batch().sample(16, np.random.default_rng(2), 1, 0.99)
    errors = [ac.clone_student(net, opt, student, cfg, b, torch.device("cpu"), 10.0) for _ in range(60)]
    assert errors[-1] < 0.2 * errors[0]


def test_a_levels_actor_from_a_students_q_head_starts_as_its_mean_decision_exactly():
    """actor_levels: the student's trunk and Q head copy in, and the actor's target is the
    student's mean decision on every frame, the full brake and a firm brake's floor included,
    with no cloning; its gradient still reaches its output layer."""
    torch.manual_seed(0)
    student_cfg = Config(action="ramp-fine", teacher="acc", decision="mean", decision_temperature=2.0, conv_channels=(4, 8, 8), hidden=32)
    student = QNetwork.of(student_cfg)
    net = ac.ActorCritic.of(Config(**{**CONT.__dict__, "actor_levels": "ramp-fine", "decision_temperature": 2.0}))
    kept = transfer_weights(student, net)
    assert "fc.2.weight" not in kept and "q1.0.weight" in kept  # the Q head is the actor's; the critic is new
    b = _batch().sample(16, np.random.default_rng(4), 1, 0.99)
    for bias in (None, 0, 2):  # as trained; the full brake the argmax; a firm brake (-0.6) the argmax
        if bias is not None:
            with torch.no_grad():
                student.fc[-1].bias[bias] += 1e3
                net.fc[-1].bias[bias] += 1e3
        want = ac.student_targets(student, student_cfg, b.frames, b.speeds, b.controls)
        got = net.actor(net.features(b.frames, b.speeds, b.controls))
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
        assert bias != 0 or (got == -1.0).all()
        assert bias != 2 or (got <= -0.6).all()
    with torch.no_grad():
        net.fc[-1].bias[:3] = student.fc[-1].bias[:3] = 0.0  # no argmax alone: the softmax mean decides
    z = net.features(b.frames, b.speeds, b.controls).detach()
    net.actor(z).sum().backward()
    assert net.fc[-1].weight.grad.abs().sum() > 0


def test_an_anchor_pulls_the_actor_to_the_students_decision():
    """bc_weight (TD3+BC): with a heavy weight the actor's distance to the anchor falls,
    and the logged distance is that mean squared error."""
    torch.manual_seed(0)
    cfg = Config(**{**CONT.__dict__, "bc_weight": 20.0, "init_from": "student.pt", "shift_pad": 0})
    net = ac.ActorCritic.of(cfg)
    target = ac.target_of(net)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    b = _batch().sample(8, np.random.default_rng(1), 3, 0.99)
    anchor = torch.full((8,), -0.3)
    dist = lambda: float(((net.actor(net.features(b.frames, b.speeds, b.controls)) - anchor) ** 2).mean())  # noqa: E731
    with torch.no_grad():
        first = dist()
    losses = [ac.update(net, target, opt, b, cfg, 0.0, torch.device("cpu"), log=True, anchor=anchor) for _ in range(40)]
    assert losses[0].bc is not None and np.isfinite(losses[0].bc)
    with torch.no_grad():
        assert dist() < 0.2 * first


@pytest.mark.parametrize(
    ("changes", "field"),
    [({"teacher": "acc"}, "teacher"), ({"aux_gap": 1.0}, "aux_gap"), ({"bc_steps": 5}, "bc_steps"), ({"critic_tau": 0.0}, "critic_tau"),
     ({"shift_pad": 17}, "shift_pad"), ({"noise_end": -0.1}, "noise_end"), ({"critic_warmup": -1}, "critic_warmup"),
     ({"actor_levels": "fine"}, "actor_levels"), ({"bc_weight": -1.0}, "bc_weight"), ({"bc_weight": 1.0}, "bc_weight"),
     ({"trunk_training": "actor"}, "trunk_training"), ({"trunk_training": "frozen"}, "trunk_training"),
     ({"trunk_training": "critic-copy", "init_from": "x.pt", "recurrent": "gru"}, "trunk_training")],
)  # fmt: skip
def test_config_refuses_what_the_actor_critic_does_not_do(changes, field):
    with pytest.raises(ConfigError) as err:
        Config(action="continuous", **changes)
    assert err.value.field == field
    with pytest.raises(ConfigError, match="continuous"):
        Config(bc_steps=3, init_from="x.pt")  # a DQN run clones nothing
    with pytest.raises(ConfigError, match="critic_warmup.*continuous"):
        Config(critic_warmup=100)  # nor has it an actor to hold
    with pytest.raises(ConfigError, match="actor_levels.*continuous"):
        Config(actor_levels="ramp-fine")
    with pytest.raises(ConfigError, match="bc_weight.*continuous"):
        Config(bc_weight=1.0, init_from="x.pt")
    with pytest.raises(ConfigError, match="trunk_training.*continuous"):
        Config(trunk_training="frozen", init_from="x.pt")


@pytest.mark.slow
def test_a_tiny_run_resumed_equals_an_uninterrupted_one_tensor_for_tensor(tmp_path):
    whole = train(CONT, tmp_path / "whole", progress=False)
    train(Config(**{**CONT.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)  # at an episode end (3 s)
    resumed = train(CONT, tmp_path / "split", resume=True, progress=False)
    assert whole["steps"] == resumed["steps"] == 100 and whole["updates"] == resumed["updates"] > 0
    a, b = (torch.load(p / "latest.pt", weights_only=True) for p in (tmp_path / "whole", tmp_path / "split"))
    assert a["rng"]["numpy"] == b["rng"]["numpy"] and torch.equal(a["rng"]["torch"], b["rng"]["torch"])
    for part in ("model", "target"):
        for key in a[part]:
            torch.testing.assert_close(a[part][key], b[part][key], rtol=0, atol=0)
    for k, s in a["optimizer"]["state"].items():
        for name in ("exp_avg", "exp_avg_sq"):
            torch.testing.assert_close(s[name], b["optimizer"]["state"][k][name], rtol=0, atol=0)
    rows = lambda p: [(r["step"], r["name"], r["value"]) for r in csv.DictReader(open(p / "scalars.csv")) if r["name"].startswith("losses/")]  # noqa: E731
    names = {n for _, n, _ in rows(tmp_path / "whole")}
    assert {ac.CRITIC_NAME, ac.ACTOR_NAME, ac.VALUES_NAME} <= names
    assert rows(tmp_path / "whole") == rows(tmp_path / "split")
    # vacc drive: the continuous checkpoint drives, its forces ramped
    log = tmp_path / "drive.csv"
    result = CliRunner().invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(tmp_path / "whole" / "latest.pt"),
                                       "--trajectory", "test-1", "--duration", "3", "--log", str(log), "--quiet"])  # fmt: skip
    assert result.exit_code == 0, result.output
    forces = [float(r["force"]) for r in csv.DictReader(open(log)) if r.get("force")]
    assert len(forces) > 20 and all(abs(b - a) <= 0.04 + 1e-6 or b == -1.0 for a, b in zip(forces, forces[1:], strict=False))


@pytest.mark.slow
def test_init_from_a_dqn_copies_its_trunk_and_clones_its_decision(tmp_path):
    student_cfg = Config(action="ramp-fine", conv_channels=(4, 8, 8), hidden=32)
    torch.manual_seed(3)
    student = QNetwork.of(student_cfg)
    save_policy(student, student_cfg, tmp_path / "student.pt")
    cfg = Config(**{**CONT.__dict__, "init_from": str(tmp_path / "student.pt"), "bc_steps": 40, "total_steps": 40})
    summary = train(cfg, tmp_path / "run", progress=False)
    net, _ = load_policy(tmp_path / "run" / "latest.pt")
    assert isinstance(net, ac.ActorCritic) and summary["updates"] > 0
    bc = [float(r["value"]) for r in csv.DictReader(open(tmp_path / "run" / "scalars.csv")) if r["name"] == ac.BC_NAME]
    assert len(bc) == 1 and np.isfinite(bc[0])


@pytest.mark.slow
def test_until_learning_starts_the_student_drives_so_the_clone_sees_its_states(tmp_path):
    """With --bc-steps, every transition before the first update is the student's decision
    (no noise here), so the clone learns it on the states the student drives into."""
    student_cfg = Config(action="ramp-fine", conv_channels=(4, 8, 8), hidden=32)
    torch.manual_seed(5)
    student = QNetwork.of(student_cfg)
    save_policy(student, student_cfg, tmp_path / "student.pt")
    cfg = Config(**{**CONT.__dict__, "init_from": str(tmp_path / "student.pt"), "bc_steps": 5, "total_steps": 30, "learning_starts": 30,
                    "noise_start": 0.0, "noise_end": 0.0, "checkpoint_every": 30})  # fmt: skip
    train(cfg, tmp_path / "run", progress=False)
    memory = ReplayMemory(cfg.buffer_size, cfg.frame_stack, 2, n_controls=2, continuous=True)
    memory.load(next((tmp_path / "run").glob("replay*.npz")))
    b = memory.sample(16, np.random.default_rng(0))
    want = ac.student_targets(student, student_cfg, b.frames, b.speeds, b.controls)
    torch.testing.assert_close(b.actions, want.to(torch.float32), rtol=0, atol=1e-6)
    assert want.std() > 0  # the student decides, not a constant


@pytest.mark.slow
@pytest.mark.parametrize("trunk", ["critic", "critic-copy"])
def test_a_run_anchored_to_its_student_logs_the_distance_and_resumes_exactly(tmp_path, trunk):
    """--bc-weight with --actor-levels: the actor starts as the student and is anchored to it;
    the distance is logged while the actor learns; a resumed run equals an uninterrupted one.
    With the critic's own copy of the trunk, the copy starts as the student's and learns while
    the actor's stays the student's."""
    student_cfg = Config(action="ramp-fine", conv_channels=(4, 8, 8), hidden=32)
    torch.manual_seed(7)
    save_policy(QNetwork.of(student_cfg), student_cfg, tmp_path / "student.pt")
    cfg = Config(**{**CONT.__dict__, "init_from": str(tmp_path / "student.pt"), "bc_weight": 0.5, "actor_levels": "ramp-fine", "critic_warmup": 3,
                    "trunk_training": trunk})  # fmt: skip
    train(cfg, tmp_path / "whole", progress=False)
    if trunk == "critic-copy":
        student = torch.load(tmp_path / "student.pt", weights_only=True)["model"]
        run = torch.load(tmp_path / "whole" / "latest.pt", weights_only=True)["model"]
        assert torch.equal(run["conv.0.weight"], student["conv.0.weight"])
        assert not torch.equal(run["critic_conv.0.weight"], student["conv.0.weight"])
    train(Config(**{**cfg.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = (torch.load(p / "latest.pt", weights_only=True) for p in (tmp_path / "whole", tmp_path / "split"))
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    bc = [float(r["value"]) for r in csv.DictReader(open(tmp_path / "whole" / "scalars.csv")) if r["name"] == ac.BC_NAME]
    assert len(bc) >= 2 and all(np.isfinite(bc))
