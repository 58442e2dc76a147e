"""DrQ-v2 from pixels (Yarats et al. 2021) for the "continuous" action type.

Read top to bottom, as CleanRL's ``sac_continuous_action.py``: the network, the
augmentation, the exploration noise, the update (critic, then actor, then the critic's
target), the policy that drives, and the behaviour-cloning warm start from a DQN student.
The loop, the replay memory, the seeding block, the checkpoints and the scalars are the
DQN's (:mod:`agent_client.rl.train`, :class:`agent_client.rl.learner.Learner`): only the
network, the update and how an action is drawn differ.

Why DrQ-v2 rather than SAC-with-DrQ or TD3 (docs/training.md, "The actor-critic"): its
actor is deterministic, so a decision is one pass of the DQN's own trunk and a tanh (as
fast as the DQN's argmax); its exploration is a scheduled Gaussian noise drawn from the
acting generator, so a run stays a function of its seed; it uses n-step returns, which the
replay memory already computes; and it needs no entropy temperature to tune.

Network: the DQN's convolutions (the same trunk, :class:`~agent_client.rl.network.QNetwork`'s
layer names, so a DQN checkpoint's perception copies over) feed

* the actor: ``fc`` (hidden, ReLU, 1 output) and a tanh: the target force in [-1, 1]; or,
  with ``actor_levels`` a ramp type, ``fc`` (hidden, ReLU, one output per level) and the
  softmax mean of the levels (:func:`mean_target`, a DQN student's mean decision), so that a
  student's Q head copies in and the actor starts as its decision, exactly;
* the critic: a ``critic_trunk`` (hidden, LayerNorm, tanh) and two heads ``q1``, ``q2``
  over (trunk, action) (clipped double Q). Only the critic's gradient trains the
  convolutions; the actor reads them detached (DrQ-v2). With ``trunk_training`` "frozen"
  nothing trains them; with "critic-copy" the critic reads and trains its own copy,
  ``critic_conv``, and the actor's stay as initialised.
"""

from __future__ import annotations

import copy
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from agent_client.actions import EMERGENCY_LEVEL, FULL_BRAKE_TARGET, make_action_type
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.network import (
    FIRM_BRAKE,
    Decision,
    GRUState,
    batch_of_one,
    gru_cell,
    scale_frames,
)
from agent_client.rl.replay import flat_transitions

__all__ = ["ActorCritic", "RecurrentActorCritic", "ActorPolicy", "update_sequences", "ACLosses", "random_shift", "explore", "update", "student_targets", "clone_student", "level_values", "mean_target", "anchor_targets", "ACTOR_NAME", "CRITIC_NAME", "VALUES_NAME", "BC_NAME",
           "network_of", "policy_of", "recurrent_start", "noise_std", "soft_update", "target_of", "noisy", "student_target"]

CRITIC_NAME = "losses/critic"
ACTOR_NAME = "losses/actor"
VALUES_NAME = "losses/q_values"  # the mean of min(Q1, Q2) at the stored actions
BC_NAME = "losses/bc"  # the behaviour-cloning warm start's mean squared error


# ----------------------------------------------------------------------------- network


class ActorCritic(nn.Module):
    """The DQN's trunk with a deterministic actor and a clipped double-Q critic.

    Args:
        frame_stack: frames per observation.
        speed_scale: [m/s] host speed divisor.
        n_controls: controls per stacked frame (the continuous type's force and set speed).
        conv_channels: the convolutions' channels.
        hidden: units of the actor's and the critic's hidden layers.
        levels: the force levels the actor averages (``actor_levels``); None: a tanh.
        temperature: the softmax temperature of that mean.
        critic_copy: the critic reads its own copy of the convolutions (``trunk_training``
            "critic-copy").
    """

    recurrent = False  # RecurrentActorCritic: a state carried from step to step

    def __init__(self, frame_stack: int = 8, speed_scale: float = 30.0, n_controls: int = 2,
                 conv_channels: tuple[int, ...] = (16, 32, 64), hidden: int = 256,
                 levels: tuple[float, ...] | None = None, temperature: float = 2.0, critic_copy: bool = False):  # fmt: skip
        super().__init__()
        self.speed_scale, self.n_controls = speed_scale, n_controls
        self.temperature = temperature
        self.levels: torch.Tensor | None
        # rebuilt from the config, never saved: a tanh actor's checkpoint keeps its layout
        self.register_buffer("levels", None if levels is None else torch.tensor(levels, dtype=torch.float32), persistent=False)
        self._control_scale = torch.tensor([1.0, speed_scale][:n_controls])
        c1, c2, c3 = conv_channels
        self.conv = nn.Sequential(
            nn.Conv2d(frame_stack, c1, 5, stride=4), nn.ReLU(),
            nn.Conv2d(c1, c2, 4, stride=2), nn.ReLU(),
            nn.Conv2d(c2, c3, 3, stride=2), nn.ReLU(),
            nn.Flatten(),
        )  # fmt: skip
        with torch.no_grad():
            n_in = self.conv(torch.zeros(1, frame_stack, FRAME_H, FRAME_W)).shape[1] + frame_stack * (1 + n_controls)
        self._heads_on(n_in, hidden)
        self.q1 = nn.Sequential(nn.Linear(hidden + 1, hidden), nn.ReLU(), nn.Linear(hidden, 1))
        self.q2 = nn.Sequential(nn.Linear(hidden + 1, hidden), nn.ReLU(), nn.Linear(hidden, 1))
        self._convs: tuple[nn.Conv2d, ...] = tuple(m for m in self.conv if isinstance(m, nn.Conv2d))
        self.critic_conv = copy.deepcopy(self.conv) if critic_copy else None  # init_from copies the actor's into it
        self._critic_convs = self._convs if self.critic_conv is None else tuple(m for m in self.critic_conv if isinstance(m, nn.Conv2d))
        self._linears: tuple[nn.Linear, ...] = (self.fc[0], self.fc[2])  # type: ignore[assignment]
        self.gap_head = self.closing_head = None  # no auxiliary heads (the DDQN controller asks)

    def _heads_on(self, width: int, hidden: int) -> None:
        """The actor's and the critic's first layers, reading ``width`` features."""
        n_out = 1 if self.levels is None else len(self.levels)
        self.fc = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, n_out))  # the actor
        self.critic_trunk = nn.Sequential(nn.Linear(width, hidden), nn.LayerNorm(hidden), nn.Tanh())

    @classmethod
    def of(cls, cfg: Any) -> ActorCritic:
        """The network a :class:`~agent_client.rl.config.Config` with a continuous action
        describes (:class:`RecurrentActorCritic` with ``recurrent`` "gru")."""
        kind = RecurrentActorCritic if getattr(cfg, "recurrent", "none") == "gru" else ActorCritic
        named = getattr(cfg, "actor_levels", "none")
        levels = None if named == "none" else tuple(level_values(named).tolist())
        return kind(cfg.frame_stack, cfg.speed_scale, make_action_type(cfg.action).n_controls, tuple(cfg.conv_channels), cfg.hidden,
                    levels, cfg.decision_temperature, getattr(cfg, "trunk_training", "critic") == "critic-copy")  # fmt: skip

    @property
    def device(self) -> torch.device:
        return self._linears[0].weight.device

    def features(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, n_in]``: the flattened convolutions, the speeds and the controls (the DQN's
        first fully connected layer's input, computed as it computes it)."""
        return self._features_through(self._convs, frames, speeds, controls)

    def critic_features(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`features` through the critic's own convolutions where it has them."""
        return self._features_through(self._critic_convs, frames, speeds, controls)

    def _features_through(self, convs: tuple[nn.Conv2d, ...], frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None) -> torch.Tensor:
        x = frames if frames.is_floating_point() else scale_frames(frames)
        for conv in convs:
            x = torch.relu(F.conv2d(x, conv.weight, conv.bias, conv.stride))
        parts = [x.flatten(1), speeds.float() / self.speed_scale]  # [B, 2560], [B, S]
        if self.n_controls:
            if controls is None:
                raise ValueError("this network observes its controls (force, set speed); none were given")
            scale = self._control_scale.to(controls.device)
            parts.append((controls.float() / scale).flatten(1))  # [B, S * C]
        return torch.cat(parts, dim=1)

    def actor(self, z: torch.Tensor) -> torch.Tensor:
        """``[B]`` the target force in [-1, 1] from features ``z``."""
        h = torch.relu(F.linear(z, self._linears[0].weight, self._linears[0].bias))
        out = F.linear(h, self._linears[1].weight, self._linears[1].bias)  # [B, 1] or [B, levels]
        if self.levels is None:
            return torch.tanh(out)[:, 0]
        return mean_target(out, self.levels, self.temperature)

    def critic(self, z: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``[B]`` Q1 and Q2 of ``action`` ``[B]`` from features ``z``."""
        h = torch.cat([self.critic_trunk(z), action[:, None]], dim=1)  # [B, hidden + 1]
        return self.q1(h)[:, 0], self.q2(h)[:, 0]

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, 1]`` the actor's target force: the decision path, one pass as the DQN's."""
        return self.actor(self.features(frames, speeds, controls))[:, None]


class RecurrentActorCritic(GRUState, ActorCritic):
    """:class:`ActorCritic` over a GRU, the recurrent trunk of
    :class:`~agent_client.rl.network.RecurrentQNetwork` for the actor-critic.

    conv over the stack -> encoder (hidden, ReLU) -> GRU (hidden) -> the actor and the critic

    The GRU's output ``h`` is what the actor and the critic read, as ``z`` in
    :class:`ActorCritic`: the critic's gradient trains it, the actor reads it detached. The
    state starts at zero with each episode, and a replayed sequence is unrolled from the state
    stored with its first step (R2D2). Called without a state it refuses.
    """

    recurrent = True

    def _heads_on(self, width: int, hidden: int) -> None:
        self.encoder = nn.Sequential(nn.Linear(width, hidden), nn.ReLU())
        self.gru = nn.GRU(hidden, hidden, batch_first=True)
        super()._heads_on(hidden, hidden)

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        raise TypeError("a recurrent network decides from its state: use step() or unroll(), or drive it through ActorPolicy")

    def step(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of ``B`` observations from ``state`` ``[B, hidden]``: the actor's target ``[B]`` and the new state."""
        h = gru_cell(self.gru, self.encoder(self.features(frames, speeds, controls)), state)  # [B, H]
        return self.actor(h), h

    def unroll(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None, state: torch.Tensor,
               conv_grad: bool = True) -> torch.Tensor:  # fmt: skip
        """The GRU's outputs ``[B, L, hidden]`` over ``B`` sequences of ``L`` observations (frames
        ``[B, L, S, H, W]``, speeds ``[B, L, S]``, controls ``[B, L, S, C]``) from ``state``
        ``[B, hidden]``; ``conv_grad`` False keeps the convolutions out of the graph."""
        b, n = frames.shape[:2]
        flat = None if controls is None or not self.n_controls else controls.flatten(0, 1)
        with torch.set_grad_enabled(conv_grad and torch.is_grad_enabled()):
            z = self.features(frames.flatten(0, 1), speeds.flatten(0, 1), flat)  # [B L, n_in]
        out, _ = self.gru(self.encoder(z).view(b, n, -1), state[None])
        return out


# ------------------------------------------------------------------------ augmentation


def random_shift(x: torch.Tensor, pad: int) -> torch.Tensor:
    """DrQ's image augmentation: each stack shifted by up to ``pad`` pixels each way
    (edges replicated), the same shift for every frame of a stack; from torch's generator.

    Args:
        x: ``[B, S, H, W]`` float frames.
        pad: [px] the largest shift (0: none).
    """
    if pad == 0:
        return x
    B, _, H, W = x.shape
    padded = F.pad(x, (pad, pad, pad, pad), mode="replicate")  # [B, S, H + 2p, W + 2p]
    dy, dx = torch.randint(0, 2 * pad + 1, (2, B)).tolist()
    return torch.stack([padded[i, :, dy[i] : dy[i] + H, dx[i] : dx[i] + W] for i in range(B)])


# ------------------------------------------------------------------------- exploration


def noise_std(cfg: Any, step: int) -> float:
    """The exploration noise's standard deviation at env step ``step``: linear from
    ``noise_start`` to ``noise_end`` over ``exploration_steps`` (DrQ-v2's schedule)."""
    from agent_client.rl.network import linear_schedule

    return linear_schedule(cfg.noise_start, cfg.noise_end, cfg.exploration_steps, step)


def explore(policy: ActorPolicy, obs: dict[str, Any], std: float, rng: np.random.Generator) -> tuple[Decision, float]:
    """The actor's target plus Gaussian noise of ``std`` from the acting generator, clipped
    to [-1, 1] and rounded to float32 (what the env applies); the decision and the action to store."""
    return noisy(policy.target(obs), std, rng)


def noisy(mu: float, std: float, rng: np.random.Generator) -> tuple[Decision, float]:
    """The target ``mu`` plus Gaussian noise of ``std`` (:func:`explore`): the decision and the action to store."""
    a = float(np.float32(min(1.0, max(-1.0, mu + std * float(rng.standard_normal())))))
    return Decision(0, None, a), a


def student_target(student: nn.Module, student_cfg: Any, obs: dict[str, Any]) -> float:
    """A DQN student's decision as a force target (:func:`student_targets`) for one observation."""
    return float(student_targets(student, student_cfg, *batch_of_one(student, obs["frames"], obs["speeds"], obs.get("controls")))[0])  # type: ignore[arg-type]


# ------------------------------------------------------------------------------ update


class ACLosses(NamedTuple):
    """What a logged actor-critic step reports (the learner's scalars)."""

    critic: float
    actor: float
    q_values: float
    bc: float | None = None  # with an anchor (bc_weight): the actor's mean squared distance to the student's decision


def update(net: ActorCritic, target: ActorCritic, optimizer: torch.optim.Optimizer, b: Any, cfg: Any, std: float,
           device: torch.device, log: bool, actor: bool = True, anchor: torch.Tensor | None = None) -> ACLosses | None:  # fmt: skip
    """One DrQ-v2 step on a replay batch: the critic's n-step clipped double-Q loss and the
    actor's -min(Q1, Q2), summed into one backward and one Adam step (Adam is per tensor, so
    this is two optimisers at the same rate), then the critic's target moves ``critic_tau``.

    The actor's loss reads the critic's weights detached and the features detached, so its
    gradient reaches the actor only, and the critic's reaches the critic and the convolutions.
    Without ``actor`` (the critic's warm-up, ``critic_warmup``) the actor's loss is left out
    and the convolutions the actor reads stay too: the actor drives as cloned while the
    critic's own layers learn the values of what it does. With ``trunk_training`` "frozen"
    they stay throughout (:func:`trains_trunk`).

    With ``anchor`` ``[B]`` (the student's decision on the batch, ``bc_weight`` > 0), the
    actor's loss is TD3+BC's (Fujimoto and Gu 2021): -min(Q1, Q2) over its mean magnitude,
    plus ``bc_weight`` times the squared distance to the anchor, so that the actor improves
    on the student where the critic is sure and stays near it elsewhere.
    """
    obs = random_shift(scale_frames(b.frames.to(device)), cfg.shift_pad)  # [B, S, H, W]
    next_obs = random_shift(scale_frames(b.next_frames.to(device)), cfg.shift_pad)
    with torch.set_grad_enabled(trains_trunk(cfg, actor)):
        z = net.features(obs, b.speeds.to(device), b.controls.to(device))  # [B, n_in]
    with torch.no_grad():
        next_z = net.features(next_obs, b.next_speeds.to(device), b.next_controls.to(device))
    if net.critic_conv is None:
        return _td_step(net, target, optimizer, z, next_z, b, cfg, std, device, log, actor, anchor)
    zc = net.critic_features(obs, b.speeds.to(device), b.controls.to(device))  # its own copy trains, warm-up included
    with torch.no_grad():
        next_zc = net.critic_features(next_obs, b.next_speeds.to(device), b.next_controls.to(device))
    return _td_step(net, target, optimizer, z, next_z, b, cfg, std, device, log, actor, anchor, (zc, next_zc))


def update_sequences(net: RecurrentActorCritic, target: RecurrentActorCritic, optimizer: torch.optim.Optimizer, seq: Any,
                     cfg: Any, std: float, device: torch.device, log: bool, actor: bool = True,
                     anchor: torch.Tensor | None = None) -> ACLosses | None:  # fmt: skip
    """:func:`update` on replayed sequences (:class:`~agent_client.rl.replay.SequenceSamples`)
    for the recurrent trunk: each sequence shifted as one, unrolled from its stored state, and
    the one-step losses taken on its steps past the burn-in (R2D2)."""
    frames = scale_frames(seq.frames.to(device))  # [B, L + 1, S, H, W]
    frames = random_shift(frames.flatten(1, 2), cfg.shift_pad).view(frames.shape)  # one shift for a whole sequence
    with torch.set_grad_enabled(trains_trunk(cfg, actor)):  # the warm-up keeps the trunk the actor reads
        h = net.unroll(frames, seq.speeds.to(device), seq.controls.to(device), seq.states.to(device))  # [B, L + 1, H]
    keep = seq.train.to(device)  # [B, L]
    return _td_step(net, target, optimizer, h[:, :-1][keep], h[:, 1:][keep].detach(), flat_transitions(seq, cfg.gamma), cfg, std, device, log, actor, anchor)


def trains_trunk(cfg: Any, actor: bool) -> bool:
    """Whether the critic's loss trains the trunk the actor reads on this update: not in the
    warm-up, never with ``trunk_training`` "frozen" or "critic-copy" (the trunk stays the
    student's, so the actor's features do not move under it)."""
    return actor and cfg.trunk_training == "critic"


def _td_step(net: ActorCritic, target: ActorCritic, optimizer: torch.optim.Optimizer, z: torch.Tensor, next_z: torch.Tensor,
             b: Any, cfg: Any, std: float, device: torch.device, log: bool, actor: bool, anchor: torch.Tensor | None = None,
             critics: tuple[torch.Tensor, torch.Tensor] | None = None) -> ACLosses | None:  # fmt: skip
    """The losses and the step of :func:`update` on features ``z`` (with the graph) and ``next_z``
    (without); ``critics``: the critic's own features of both, where it reads its own copy."""
    zc, next_zc = (z, next_z) if critics is None else critics
    with torch.no_grad():
        noise = (torch.randn(len(next_z), device=device) * std).clamp(-cfg.noise_clip, cfg.noise_clip)  # [B]
        next_a = (net.actor(next_z) + noise).clamp(-1.0, 1.0)  # [B] target policy smoothing
        tq1, tq2 = target.critic(next_zc, next_a)
        done = b.terminated.to(device).float()  # [B]; truncations bootstrap
        terminal = b.terminal_rewards.to(device) / (1.0 - cfg.gamma) * float(cfg.absorbing_terminal)
        y = b.returns.to(device) + b.discounts.to(device) * ((1.0 - done) * torch.min(tq1, tq2) + done * terminal)  # [B]
    q1, q2 = net.critic(zc, b.actions.to(device).float())
    critic_loss = F.mse_loss(q1, y) + F.mse_loss(q2, y)
    frozen = {k: v.detach() for k, v in net.named_parameters() if k.startswith(("critic_trunk", "q1", "q2"))}
    a = net.actor(z.detach())  # [B]
    q_pi = torch.min(*_critic_with(net, frozen, zc.detach(), a))
    bc = None if anchor is None else F.mse_loss(a, anchor)
    actor_loss = -q_pi.mean() if bc is None else -q_pi.mean() / q_pi.abs().mean().detach().clamp(min=1e-6) + cfg.bc_weight * bc
    optimizer.zero_grad()
    (critic_loss + actor_loss if actor else critic_loss).backward()
    nn.utils.clip_grad_norm_(net.parameters(), cfg.max_grad_norm)
    optimizer.step()
    soft_update(net, target, cfg.critic_tau)
    if not log:
        return None
    return ACLosses(critic_loss.item(), actor_loss.item(), torch.min(q1, q2).mean().item(), None if bc is None else bc.item())


def _critic_with(net: ActorCritic, frozen: dict[str, torch.Tensor], z: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Q1, Q2 of the actor's own action ``a`` ``[B]`` on features ``z``, with the critic's weights ``frozen``."""
    trunk = F.linear(z, frozen["critic_trunk.0.weight"], frozen["critic_trunk.0.bias"])
    trunk = torch.tanh(F.layer_norm(trunk, trunk.shape[-1:], frozen["critic_trunk.1.weight"], frozen["critic_trunk.1.bias"]))
    h = torch.cat([trunk, a[:, None]], dim=1)
    out = []
    for head in ("q1", "q2"):
        x = torch.relu(F.linear(h, frozen[f"{head}.0.weight"], frozen[f"{head}.0.bias"]))
        out.append(F.linear(x, frozen[f"{head}.2.weight"], frozen[f"{head}.2.bias"])[:, 0])
    return out[0], out[1]


@torch.no_grad()
def soft_update(net: ActorCritic, target: ActorCritic, tau: float) -> None:
    """The critic's target moves ``tau`` of the way to the online critic (Polyak)."""
    online = dict(net.named_parameters())
    for name, p in target.named_parameters():
        if name.startswith(("critic_trunk", "q1", "q2")):
            p.lerp_(online[name], tau)


def target_of(net: ActorCritic) -> ActorCritic:
    """A frozen copy of ``net`` as the critic's target."""
    t = copy.deepcopy(net)
    for p in t.parameters():
        p.requires_grad_(False)
    return t


# ------------------------------------------------------------------------------ policy


class ActorPolicy:
    """The actor's decision: its target force, rounded to float32 as the env applies it
    (:class:`~agent_client.rl.network.Decision`'s ``continuous``); the full brake where that
    target is at or below :data:`~agent_client.actions.FULL_BRAKE_TARGET`, by the action type.
    A recurrent actor's state steps on with each observation and starts at zero with each episode."""

    def __init__(self, net: ActorCritic):
        self.q = net
        self._state: torch.Tensor | None = None  # a recurrent actor's state; None: the episode's start (zeros)

    def reset(self) -> None:
        """Forget the episode: a recurrent actor's state (the frame stack has none here)."""
        self._state = None

    def episode_state(self) -> dict[str, Any]:
        """A recurrent actor's state within the episode (:meth:`agent_client.rl.network.Policy.episode_state`)."""
        return {"state": None if self._state is None else self._state.clone()}

    def set_episode_state(self, saved: dict[str, Any]) -> None:
        """Take up an episode where :meth:`episode_state` left it."""
        self._state = None if saved["state"] is None else saved["state"].to(self.q.device)  # saved read onto the CPU

    def state(self) -> np.ndarray | None:
        """A recurrent actor's state before the next observation ``[hidden]`` (float32), else None
        (:meth:`agent_client.rl.network.Policy.state`)."""
        if not isinstance(self.q, RecurrentActorCritic):
            return None
        if self._state is None:
            return np.zeros(self.q.state_size, np.float32)
        return self._state[0].detach().cpu().numpy().astype(np.float32, copy=True)

    def fresh(self) -> ActorPolicy:
        """A policy of the same network at an episode's start (stateless: this one)."""
        return ActorPolicy(self.q) if self.q.recurrent else self

    def target(self, obs: dict[str, Any]) -> float:
        """The actor's target force for one stacked observation (a recurrent actor's state steps on)."""
        with torch.inference_mode():
            inputs = batch_of_one(self.q, obs["frames"], obs["speeds"], obs.get("controls"))  # type: ignore[arg-type]
            if not isinstance(self.q, RecurrentActorCritic):
                return float(self.q(*inputs)[0, 0])
            state = self.q.initial_state(1) if self._state is None else self._state
            out, self._state = self.q.step(*inputs, state)
            return float(out[0])

    def __call__(self, obs: dict[str, Any]) -> Decision:
        return Decision(0, None, float(np.float32(self.target(obs))))

    def decide(self, out: torch.Tensor, controls: np.ndarray | None = None) -> Decision:
        """The decision from the network's output ``[1]`` computed elsewhere."""
        return Decision(0, None, float(np.float32(float(out[0]))))


# ------------------------------------------------------------- warm start from a student


def level_values(action: str) -> torch.Tensor:
    """``[A]`` the force targets of a discrete action type's actions, in action order."""
    actions = make_action_type(action)
    return torch.tensor(getattr(actions, "levels", None) or [actions.force(a) for a in range(actions.n)], dtype=torch.float32)


def mean_target(out: torch.Tensor, levels: torch.Tensor, temperature: float) -> torch.Tensor:
    """``[B]`` the mean decision over ``levels`` ``[A]`` from outputs ``out`` ``[B, A]``: the
    softmax-weighted mean of the levels but the full brake, at ``temperature``, no softer than a
    firm-braking argmax; the full brake (-1) where the argmax is the full brake. Differentiable
    where the argmax does not decide alone, so an actor with these outputs learns through it."""
    top = out.argmax(dim=1)  # [B]
    keep = torch.ones(len(levels), dtype=torch.bool, device=out.device)
    keep[EMERGENCY_LEVEL] = False
    w = torch.softmax(out[:, keep] / temperature, dim=1)  # [B, A - 1]
    target = (w * levels[keep]).sum(dim=1)
    firm = levels[top] <= -FIRM_BRAKE
    target = torch.where(firm, torch.minimum(target, levels[top]), target)
    return torch.where(top == EMERGENCY_LEVEL, torch.full_like(target, -1.0), target).clamp(-1.0, 1.0)


@torch.no_grad()
def student_targets(q: nn.Module, cfg: Any, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None) -> torch.Tensor:
    """``[B]`` a DQN student's decision as a force target, batched: with the mean decision,
    :func:`mean_target` at its temperature; else its argmax level (the full brake: -1).

    The per-episode parts of :class:`~agent_client.rl.network.Policy` (brake confirmation,
    deadband, smoothing) are left out: the clone learns the mean, and the ramp smooths it.
    """
    levels = level_values(cfg.action)
    out = q(frames, speeds, controls if getattr(q, "n_controls", 0) else None)  # [B, A]
    if cfg.decision == "mean":
        return mean_target(out, levels, cfg.decision_temperature)
    top = out.argmax(dim=1)  # [B]
    return torch.where(top == EMERGENCY_LEVEL, torch.full_like(levels[top], -1.0), levels[top]).clamp(-1.0, 1.0)


def clone_student(net: ActorCritic, optimizer: torch.optim.Optimizer, student: nn.Module, student_cfg: Any, b: Any,
                  device: torch.device, max_grad_norm: float) -> float:  # fmt: skip
    """One behaviour-cloning step: the actor regresses on the student's decision
    (:func:`student_targets`) on a replay batch; returns the mean squared error.

    The actor's tanh never reaches -1: a full-brake label is asked as the continuous type's
    :data:`~agent_client.actions.FULL_BRAKE_TARGET`, which brakes fully as well. The
    convolutions stay as copied; a recurrent actor clones on replayed sequences
    (:class:`~agent_client.rl.replay.SequenceSamples`), its encoder and GRU learning with it.
    """
    if isinstance(net, RecurrentActorCritic):
        keep = b.train.to(device)  # [B, L]
        frames, speeds, controls = (t.to(device)[:, :-1][keep] for t in (b.frames, b.speeds, b.controls))  # the trained steps
        h = net.unroll(b.frames.to(device), b.speeds.to(device), b.controls.to(device), b.states.to(device), conv_grad=False)
        z = h[:, :-1][keep]  # [N, H]
    else:
        frames, speeds, controls = b.frames.to(device), b.speeds.to(device), b.controls.to(device)
        with torch.no_grad():
            z = net.features(frames, speeds, controls)  # the trunk as copied; the clone trains the actor
    y = student_targets(student, student_cfg, frames, speeds, controls)  # [B]
    if net.levels is None:  # a tanh never reaches -1
        y = y.clamp(min=FULL_BRAKE_TARGET - 0.01)
    loss = F.mse_loss(net.actor(z), y)
    optimizer.zero_grad()
    loss.backward()
    nn.utils.clip_grad_norm_(net.parameters(), max_grad_norm)
    optimizer.step()
    return loss.item()


def anchor_targets(net: ActorCritic, student: nn.Module, student_cfg: Any, b: Any, device: torch.device) -> torch.Tensor:
    """``[N]`` the student's decision (:func:`student_targets`) on the steps an update trains:
    a batch's observations, or a sequence batch's steps past the burn-in, in
    :func:`update_sequences`' order (the TD3+BC anchor of ``bc_weight``)."""
    if isinstance(net, RecurrentActorCritic):
        keep = b.train.to(device)  # [B, L]
        frames, speeds, controls = (t.to(device)[:, :-1][keep] for t in (b.frames, b.speeds, b.controls))
    else:
        frames, speeds, controls = b.frames.to(device), b.speeds.to(device), b.controls.to(device)
    return student_targets(student, student_cfg, frames, speeds, controls)


def recurrent_start(src: nn.Module) -> dict[str, torch.Tensor]:
    """What a :class:`RecurrentActorCritic` starts from in ``src`` (``init_from``), by its
    names: the convolutions; from a DQN, its hidden layer as the encoder (``fc.0`` ->
    ``encoder.0``) and a recurrent DQN's GRU; from a recurrent actor-critic, all of it. The
    actor and the critic of another network read other features, so they start afresh."""
    state = src.state_dict()
    if isinstance(src, RecurrentActorCritic):
        return dict(state)
    keep = {k: v for k, v in state.items() if k.startswith("conv.")}
    if not isinstance(src, ActorCritic):
        keep |= {"encoder.0." + k.removeprefix("fc.0."): v for k, v in state.items() if k.startswith("fc.0.")}
        keep |= {k: v for k, v in state.items() if k.startswith("gru.")}
    return keep


# ------------------------------------------------------------------ by the config


def network_of(cfg: Any) -> nn.Module:
    """The network a config describes: the actor-critic for a continuous action, else the DQN's."""
    from agent_client.actions import is_continuous
    from agent_client.rl.network import QNetwork

    return ActorCritic.of(cfg) if is_continuous(cfg.action) else QNetwork.of(cfg)


def policy_of(net: nn.Module, cfg: Any) -> Any:
    """The decision rule of ``net``: :class:`ActorPolicy` for the actor-critic, else
    :class:`~agent_client.rl.network.Policy` with the config's rule."""
    from agent_client.rl.network import Policy

    return ActorPolicy(net) if isinstance(net, ActorCritic) else Policy.of(net, cfg)  # type: ignore[arg-type]
