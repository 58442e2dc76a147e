"""The Q-network (the paper's Figure 4, scaled to a 2-core CPU) and its one inference path.

Every decision, in training, in the trainer's evaluation and in ``vacc drive``, goes
through :func:`greedy_action` or, with the mean decision, :class:`Policy`, so they
compute the same numbers to the last digit.
"""

from __future__ import annotations

import copy as _copy
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from agent_client.actions import EMERGENCY_LEVEL, make_action_type
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import DECISIONS
from agent_client.stacker import stack_picks
from protocol.constants import FORCES, N_ACTIONS

__all__ = [
    "QNetwork", "RecurrentQNetwork", "GRUState", "gru_cell", "FORCES", "N_ACTIONS", "Decision", "Policy", "greedy_action", "linear_schedule", "transfer_weights",
    "GAP_HEAD_SCALE", "CLOSING_HEAD_SCALE", "batch_of_one", "scale_frames", "ScaledFrames",
]  # fmt: skip

# The heads' outputs; their targets and losses: agent_client.rl.losses.aux_heads.
GAP_HEAD_SCALE = 55.0  # [m] the gap head's output is log(gap / this)
CLOSING_HEAD_SCALE = 5.0  # [m/s] the closing head's output is the closing speed over this


_FRAME_SCALE = np.float32(255.0)  # scale_frames' divisor, for numpy (float32 division, as torch's)


def scale_frames(frames: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """uint8 frames as the network's input: float, /255 (in one pass: ``frames.float() / 255.0``
    to the bit), into ``out`` if given."""
    return torch.div(frames, 255.0, out=out)


class QNetwork(nn.Module):
    """Convolutions over the frame stack (frames as channels); the host-speed sequence
    (and, for the "steps" action type, the controls sequence) joins at the fully
    connected layers; one Q-value per action out (21 for the paper's force levels).

    conv 5x5/4 (16) -> conv 4x4/2 (32) -> conv 3x3/2 (64) -> 2560 features
    [2560 features, 8 speeds / speed_scale] -> fc 256 -> fc 21

    (those widths are the defaults: ``conv_channels`` and ``hidden`` make it narrower)

    About 693 k parameters (2.8 MB as float32). The first layer is a 5x5 kernel at
    stride 4 rather than Atari's 8x8: on one CPU thread it cut a batch-32 update
    from about 80 ms to 58 ms and the batch-1 forward by about 15 %.

    The forward pass takes frames, speeds and the agent's own controls only
    (:data:`agent_client.actions.CONTROLS`: its last force and the driver's set speed):
    there is no way to give it the gap. With ``gap_head`` (``Config.aux_gap``), a second
    output layer on the hidden layer estimates the gap (:meth:`q_and_gap`), trained on the
    simulator's gap as an auxiliary loss; the Q-values do not read it. ``closing_head``
    (``Config.aux_closing``) does the same for the closing speed (:meth:`with_heads`).
    """

    recurrent = False  # RecurrentQNetwork: a state carried from step to step

    def __init__(
        self, frame_stack: int = 8, n_actions: int = N_ACTIONS, speed_scale: float = 30.0, n_controls: int = 0,
        gap_head: bool = False, closing_head: bool = False, conv_channels: tuple[int, ...] = (16, 32, 64), hidden: int = 256,
    ):  # fmt: skip
        super().__init__()
        self.speed_scale, self.n_controls = speed_scale, n_controls
        # force as it is (in [-1, 1]); set speed over the speed scale
        self._control_scale = torch.tensor([1.0, speed_scale][:n_controls])
        c1, c2, c3 = conv_channels
        self.conv = nn.Sequential(
            nn.Conv2d(frame_stack, c1, 5, stride=4),
            nn.ReLU(),
            nn.Conv2d(c1, c2, 4, stride=2),
            nn.ReLU(),
            nn.Conv2d(c2, c3, 3, stride=2),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n_conv = self.conv(torch.zeros(1, frame_stack, FRAME_H, FRAME_W)).shape[1]
        self._convs: tuple[nn.Conv2d, ...] = tuple(m for m in self.conv if isinstance(m, nn.Conv2d))
        self.fc = nn.Sequential(nn.Linear(n_conv + frame_stack * (1 + n_controls), hidden), nn.ReLU(), nn.Linear(hidden, n_actions))
        # plain tuples, not attributes, so that the state dict keeps one name per tensor
        self._linears: tuple[nn.Linear, ...] = tuple(m for m in self.fc if isinstance(m, nn.Linear))
        # created after the layers above, so that a network with the head draws their initial weights as one without
        self.gap_head = nn.Linear(hidden, 1) if gap_head else None
        self.closing_head = nn.Linear(hidden, 1) if closing_head else None

    @classmethod
    def of(cls, cfg: Any) -> QNetwork:
        """The network a :class:`~agent_client.rl.config.Config` describes."""
        from agent_client.actions import make_action_type

        actions = make_action_type(cfg.action)
        kind = RecurrentQNetwork if getattr(cfg, "recurrent", "none") == "gru" else QNetwork
        return kind(cfg.frame_stack, actions.n, cfg.speed_scale, actions.n_controls, gap_head=cfg.aux_gap > 0.0, closing_head=cfg.aux_closing > 0.0,
                    conv_channels=tuple(cfg.conv_channels), hidden=cfg.hidden)  # fmt: skip

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        """Q-values.

        Args:
            frames: uint8 ``[B, frame_stack, 105, 150]``, or those frames already as
                :func:`scale_frames` gives them (any floating dtype is taken as scaled).
            speeds: host speeds [m/s], ``[B, frame_stack]``.
            controls: ``[B, frame_stack, n_controls]`` (force, set speed [m/s]); only
                for a network built with ``n_controls > 0``, which needs them.

        Returns:
            ``[B, A]`` Q-values, one per action.
        """
        hidden = self._hidden(frames, speeds, controls)
        out = self._linears[1]
        return F.linear(hidden, out.weight, out.bias)  # [B, A]

    def q_and_gap(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The Q-values ``[B, A]`` and the gap head's raw output ``[B]`` (log(gap / 55 m);
        :meth:`gap_estimate` in metres), from one pass. Only for a network with the head."""
        if self.gap_head is None:
            raise ValueError("this network has no gap head (trained without --aux-gap)")
        q, gap, _ = self.with_heads(frames, speeds, controls)
        assert gap is not None
        return q, gap

    def with_heads(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """From one pass: the Q-values ``[B, A]``, and the raw outputs ``[B]`` of the gap head
        and of the closing head (:meth:`gap_estimate`, :meth:`closing_estimate`), None where
        the network has no such head."""
        hidden = self._hidden(frames, speeds, controls)
        out = self._linears[1]
        heads = [None if h is None else F.linear(hidden, h.weight, h.bias)[:, 0] for h in (self.gap_head, self.closing_head)]
        return F.linear(hidden, out.weight, out.bias), heads[0], heads[1]

    @property
    def device(self) -> torch.device:
        """Where the weights are; cheaper per decision than ``next(self.parameters())``, which walks the modules."""
        return self._linears[0].weight.device

    @staticmethod
    def gap_estimate(raw: torch.Tensor) -> torch.Tensor:
        """The gap head's raw output in metres."""
        return GAP_HEAD_SCALE * torch.exp(raw)

    @staticmethod
    def closing_estimate(raw: torch.Tensor) -> torch.Tensor:
        """The closing head's raw output as a closing speed [m/s] (positive: gaining on the lead)."""
        return CLOSING_HEAD_SCALE * raw

    def _hidden(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None) -> torch.Tensor:
        """The hidden layer's activations ``[B, 256]``."""
        # The layers are called functionally, with in-place ReLUs: the same kernels and so the
        # same numbers as calling the modules, without their per-call overhead (a third of
        # a batch-1 decision).
        x = frames if frames.is_floating_point() else scale_frames(frames)
        for conv in self._convs:
            x = torch.relu_(F.conv2d(x, conv.weight, conv.bias, conv.stride))
        x = x.flatten(1)  # [B, 2560]
        v = speeds.float() / self.speed_scale  # [B, S]
        if not self.n_controls:
            z = torch.cat([x, v], dim=1)
        elif controls is None:
            raise ValueError("this network observes its controls (force, set speed); none were given")
        else:
            scale = self._control_scale if controls.device.type == "cpu" else self._control_scale.to(controls.device)
            c = (controls.float() / scale).flatten(1)  # [B, S * C]
            z = torch.cat([x, v, c], dim=1)
        hidden = self._linears[0]
        return torch.relu_(F.linear(z, hidden.weight, hidden.bias))  # [B, 256]


class GRUState:
    """What a network with a one-layer GRU (``self.gru``) carries between steps: the size of
    its state and the state at an episode's start (zeros)."""

    gru: nn.GRU
    device: torch.device

    @property
    def state_size(self) -> int:
        return self.gru.hidden_size

    def initial_state(self, batch: int = 1) -> torch.Tensor:
        """The state at an episode's start: zeros ``[batch, hidden]``."""
        return torch.zeros(batch, self.gru.hidden_size, device=self.device)


class RecurrentQNetwork(GRUState, QNetwork):
    """:class:`QNetwork` with a GRU between its hidden layer and its outputs: the paper's third
    item of future work, a recurrent network over the whole sequence of frames rather than a
    fixed stack alone (R2D2, Kapturowski et al. 2019, with a GRU for an LSTM).

    conv over the stack -> fc (hidden, ReLU) -> GRU (hidden) -> fc (actions), and the heads

    The state ``[B, hidden]`` is carried from step to step (:meth:`step`) and starts at zero
    with each episode; a replayed sequence is unrolled (:meth:`unroll`) from the state stored
    with its first step. The layers it shares with :class:`QNetwork` keep their names, so a
    frame-stack checkpoint's perception copies over (``init_from``). Called without a state
    it refuses: a decision without the state would be silently another policy's.
    """

    recurrent = True

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        width = self._linears[0].out_features
        self.gru = nn.GRU(width, width, batch_first=True)

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> torch.Tensor:
        raise TypeError("a recurrent network decides from its state: use step() or unroll(), or drive it through Policy")

    def with_heads(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        raise TypeError("a recurrent network decides from its state: use step() or unroll(), or drive it through Policy")

    def step(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
        """One step of ``B`` observations (as :meth:`QNetwork.forward`'s) from ``state``
        ``[B, hidden]``: the outputs ``[B, A]``, the heads' raw outputs ``[B]`` (or None) and the new state."""
        h = gru_cell(self.gru, self._hidden(frames, speeds, controls), state)  # [B, H]
        return (*self._heads(h), h)

    def unroll(self, frames: torch.Tensor, speeds: torch.Tensor, controls: torch.Tensor | None, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
        """``B`` sequences of ``L`` observations (frames ``[B, L, S, H, W]``, speeds ``[B, L, S]``,
        controls ``[B, L, S, C]``) from ``state`` ``[B, hidden]``: outputs ``[B, L, A]``, the heads'
        ``[B, L]`` (or None) and the final state."""
        b, n = frames.shape[:2]
        flat_controls = None if controls is None or not self.n_controls else controls.flatten(0, 1)
        x = self._hidden(frames.flatten(0, 1), speeds.flatten(0, 1), flat_controls).view(b, n, -1)  # [B, L, H]
        out, h = self.gru(x, state[None])
        return (*self._heads(out), h[0])

    def _heads(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        out = self._linears[1]
        heads = [None if h is None else F.linear(z, h.weight, h.bias)[..., 0] for h in (self.gap_head, self.closing_head)]
        return F.linear(z, out.weight, out.bias), heads[0], heads[1]


def gru_cell(gru: nn.GRU, x: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
    """One step of a one-layer ``gru`` on inputs ``x`` ``[B, in]`` from ``state`` ``[B, hidden]``:
    the new state. nn.GRU's cell written out: at batch 1 the module's own call costs more
    than its arithmetic."""
    w_ih, w_hh, b_ih, b_hh = gru.all_weights[0]
    xr, xz, xn = F.linear(x, w_ih, b_ih).chunk(3, 1)
    hr, hz, hn = F.linear(state, w_hh, b_hh).chunk(3, 1)
    r, z = torch.sigmoid(xr + hr), torch.sigmoid(xz + hz)
    n = torch.tanh(xn + r * hn)
    return n + z * (state - n)  # (1 - z) n + z h


def batch_of_one(q: QNetwork, frames: np.ndarray | torch.Tensor, speeds: np.ndarray, controls: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """One stacked observation as the network's inputs: a batch of one on its device
    (frames uint8, or scaled as :class:`ScaledFrames` keeps them)."""
    device = q.device
    c = None if controls is None else torch.from_numpy(controls)[None]
    f, v = torch.as_tensor(frames)[None], torch.from_numpy(speeds)[None]
    if device.type == "cpu":  # already there: skip three no-op dispatches, a twentieth of a decision
        return f, v, c
    return f.to(device), v.to(device), None if c is None else c.to(device)


class ScaledFrames:
    """The frames of the stacks a :class:`~agent_client.stacker.FrameStacker` builds, kept
    as the network's input: :func:`scale_frames` of its uint8 stack, to the bit.

    A decision at batch 1 spent a tenth of its time stacking eight frames and scaling
    them, though seven of the eight were scaled before. Here each frame is scaled once, as
    it arrives, into one ring per phase of the stride (each slot written twice, ``n``
    apart), so that a full stack is a view of ``frame_stack`` consecutive slots, not a copy.

    Args:
        frame_stack: frames per stack.
        stack_stride: control steps between stacked frames.
    """

    def __init__(self, frame_stack: int = 8, stack_stride: int = 1):
        self.frame_stack, self.stack_stride = frame_stack, stack_stride
        self._span = (frame_stack - 1) * stack_stride + 1  # frames a full stack spans
        self._rings = rings = torch.empty((stack_stride, 2 * frame_stack, FRAME_H, FRAME_W))
        # every view made once: indexing a tensor from Python costs microseconds a decision
        # numpy views of the slots: numpy's uint8 / float32 is torch's to the bit, and costs
        # half of torch.div(out=) and copy_ right after a forward has left the caches cold
        arrays = rings.numpy()
        self._slots = [[(arrays[r, k], arrays[r, k + frame_stack]) for k in range(frame_stack)] for r in range(stack_stride)]
        self._stacks = [[rings[r, k + 1 : k + frame_stack + 1] for k in range(frame_stack)] for r in range(stack_stride)]
        self._pushed = 0

    def reset(self) -> None:
        """Forget the previous episode."""
        self._pushed = 0

    def push(self, frame: np.ndarray) -> torch.Tensor:
        """Add one preprocessed uint8 frame ``[H, W]``; the stack ``[frame_stack, H, W]``,
        oldest first, valid until the next push (a view into the rings)."""
        n, stride = self.frame_stack, self.stack_stride
        i = self._pushed
        ring, slot = i % stride, (i // stride) % n
        first, second = self._slots[ring][slot]
        np.divide(frame, _FRAME_SCALE, out=first)  # scale_frames, in numpy (see __init__)
        second[...] = first
        self._pushed += 1
        if self._pushed >= self._span:  # the stack is this ring's last n frames
            return self._stacks[ring][slot]
        # episode start: nothing overwritten yet, so history index = push count
        return torch.stack([self._rings[k % stride, (k // stride) % n] for k in stack_picks(self._pushed, n, stride)])


def greedy_action(q: QNetwork, frames: np.ndarray | torch.Tensor, speeds: np.ndarray, controls: np.ndarray | None = None) -> int:
    """argmax_a Q(s, a) for one stacked observation (frames ``[S, H, W]``, speeds ``[S]``,
    controls ``[S, C]`` for a network that observes them)."""
    with torch.inference_mode():
        qv = q(*batch_of_one(q, frames, speeds, controls))  # [1, A]
    return int(qv.argmax(dim=1).item())


# (mean decision) where the argmax level brakes at least this hard (force; 0.3 is 1.65 m/s^2),
# the target brakes no softer than it: averaging must not delay a real brake.
FIRM_BRAKE = 0.3


class Decision(NamedTuple):
    """What a policy asks of its action type: the argmax ``action``, or, where ``target``
    is not None, a ramp toward that force (the mean decision), or, where ``continuous`` is
    not None, the continuous action type's target force (the actor's, which may be the full brake)."""

    action: int
    target: float | None = None
    continuous: float | None = None

    def step(self, env: Any) -> Any:
        """Step a :class:`~agent_client.env.VisionACCEnv` with it; the env step's returns."""
        if self.continuous is not None:
            return env.step(np.array([self.continuous], np.float32))
        return env.step(self.action) if self.target is None else env.step_toward(self.target)


class Policy:
    """A network and its decision rule (``Config.decision``).

    "argmax": the action with the largest output (:func:`greedy_action`). "mean": for a
    student trained on a teacher's labels by cross-entropy, whose outputs are logits over
    the ramp's target levels, the ramp moves toward their softmax-weighted mean at
    ``temperature``, leaving the full brake out; a student torn between two levels then
    asks for the force between them instead of flipping from one to the other. Where the
    full brake is the argmax, it acts at once, as ever; where the argmax brakes at least
    :data:`FIRM_BRAKE`, the target brakes no softer than it; and where the softmax gives the
    full brake at least ``brake_share`` (in ``brake_confirm`` decisions in a row), it acts
    at once too. With a ``deadband``, a target within that much force of the held one (the
    last force, the first of the observed controls) keeps the held force; with a ``smoothing`` below 1, the target is that share
    of the way from the held force; neither where it brakes at least :data:`FIRM_BRAKE`.

    Args:
        q: the network.
        decision: one of :data:`DECISIONS`.
        levels: the action type's target levels (the mean decision).
        temperature: the softmax's temperature (the mean decision).
        brake_share: the full brake's softmax share that brakes fully (the mean decision; 1: only the argmax).
        brake_confirm: decisions in a row that must reach ``brake_share`` (1: at once). The
            count is state: :meth:`reset` it with each episode, or decide with a :meth:`fresh` copy.
        full_brake_confirm: decisions in a row whose argmax must be the full brake before it
            acts at once (the mean decision; 1: at once); until then the target is the full
            brake, through the ramp. State, as ``brake_confirm``'s.
        deadband: force within which the held force stays (the mean decision; 0: off).
        smoothing: the share of the way to the target asked each step (the mean decision; 1: off).
    """

    def __init__(self, q: QNetwork, decision: str = "argmax", levels: Sequence[float] = (), temperature: float = 1.0,
                 brake_share: float = 1.0, deadband: float = 0.0, smoothing: float = 1.0, brake_confirm: int = 1,
                 full_brake_confirm: int = 1):
        if decision not in DECISIONS:
            raise ValueError(f"decision {decision!r} is not one of {DECISIONS}")
        n_out = q.fc[-1].out_features
        if decision == "mean" and len(levels) != n_out:
            raise ValueError(f"the mean decision needs one target level per output ({n_out}), got {len(levels)}")
        self.q, self.decision, self.temperature, self.brake_share = q, decision, float(temperature), float(brake_share)
        self.deadband, self.smoothing = float(deadband), float(smoothing)
        self.brake_confirm, self._share_streak = int(brake_confirm), 0  # decisions in a row at the brake share
        self.full_brake_confirm, self._full_streak = int(full_brake_confirm), 0  # decisions in a row with the full brake the argmax
        self._all_levels = tuple(float(x) for x in levels)
        self._levels = self._all_levels[:EMERGENCY_LEVEL] + self._all_levels[EMERGENCY_LEVEL + 1 :]
        self._state: torch.Tensor | None = None  # a recurrent network's state; None: the episode's start (zeros)

    @classmethod
    def of(cls, q: QNetwork, cfg: Any) -> Policy:
        """The policy a :class:`~agent_client.rl.config.Config` describes."""
        levels = getattr(make_action_type(cfg.action), "levels", ())
        return cls(q, cfg.decision, levels if cfg.decision == "mean" else (), cfg.decision_temperature, cfg.decision_brake_share,
                   cfg.decision_deadband, cfg.decision_smoothing, cfg.decision_brake_confirm, cfg.decision_full_brake_confirm)

    def reset(self) -> None:
        """Start an episode: forget the decisions in a row at the brake share or the full brake,
        and a recurrent network's state."""
        self._share_streak = self._full_streak = 0
        self._state = None

    def episode_state(self) -> dict[str, Any]:
        """What it carries from one decision to the next within an episode (the decisions in a row, a
        recurrent state): a checkpoint cut mid-episode keeps it, as the network then was."""
        return {"share_streak": self._share_streak, "full_streak": self._full_streak, "state": None if self._state is None else self._state.clone()}

    def set_episode_state(self, saved: dict[str, Any]) -> None:
        """Take up an episode where :meth:`episode_state` left it."""
        self._share_streak, self._full_streak = int(saved["share_streak"]), int(saved["full_streak"])
        self._state = None if saved["state"] is None else saved["state"].to(self.q.device)  # saved read onto the CPU

    def state(self) -> np.ndarray | None:
        """A recurrent network's state before the next observation ``[hidden]`` (float32,
        a copy: what the replay memory stores with that observation); None for a frame stack."""
        if not isinstance(self.q, RecurrentQNetwork):
            return None
        if self._state is None:
            return np.zeros(self.q.state_size, np.float32)
        return self._state[0].detach().cpu().numpy().astype(np.float32, copy=True)

    def outputs(self, frames: Any, speeds: np.ndarray, controls: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The outputs ``[1, A]`` and the heads' raw outputs ``[1]`` (or None) for one stacked
        observation; a recurrent network's state steps on."""
        with torch.inference_mode():
            inputs = batch_of_one(self.q, frames, speeds, controls)
            if not isinstance(self.q, RecurrentQNetwork):
                return self.q.with_heads(*inputs)
            state = self.q.initial_state(1) if self._state is None else self._state
            q, gap, closing, self._state = self.q.step(*inputs, state)
            return q, gap, closing

    def fresh(self) -> Policy:
        """A copy for one episode (the same network and rule, its own state)."""
        copy = _copy.copy(self)
        copy.reset()
        return copy

    def __call__(self, obs: dict[str, Any]) -> Decision:
        """The decision for one stacked observation (frames, speeds and, if observed, controls)."""
        if self.q.recurrent:
            return self.decide(self.outputs(obs["frames"], obs["speeds"], obs.get("controls"))[0][0], obs.get("controls"))
        if self.decision == "argmax":
            return Decision(greedy_action(self.q, obs["frames"], obs["speeds"], obs.get("controls")))
        with torch.inference_mode():
            out = self.q(*batch_of_one(self.q, obs["frames"], obs["speeds"], obs.get("controls")))[0]
        return self.decide(out, obs.get("controls"))

    def decide(self, out: torch.Tensor, controls: np.ndarray | None = None) -> Decision:
        """The decision from the network's outputs ``[A]`` for one observation, computed
        elsewhere (e.g. by :meth:`QNetwork.q_and_gap`), and its controls ``[S, C]`` (the
        deadband and the smoothing read the held force there); the same as :meth:`__call__`'s."""
        if self.decision == "argmax":
            return Decision(int(out.argmax().item()))
        # In plain Python floats: 21 numbers cost less here than a tensor op's dispatch, and
        # math.fsum makes each sum exact, so the target is the same on any machine.
        out_ = out.tolist()  # float64, exactly the outputs
        action = max(range(len(out_)), key=out_.__getitem__)  # the first of equal maxima, as argmax
        self._full_streak = self._full_streak + 1 if action == EMERGENCY_LEVEL else 0
        if self._full_streak >= self.full_brake_confirm:
            self._share_streak += 1  # a full brake in progress: a share that follows goes on braking
            return Decision(action)
        top, t = out_[action], self.temperature
        weights = [math.exp((x - top) / t) for x in out_]  # the softmax's, before normalising
        if self.brake_share < 1.0:
            at_share = weights[EMERGENCY_LEVEL] / math.fsum(weights) >= self.brake_share
            self._share_streak = self._share_streak + 1 if at_share else 0
            if self._share_streak >= self.brake_confirm:
                return Decision(EMERGENCY_LEVEL)
        del weights[EMERGENCY_LEVEL]  # the mean leaves the full brake out
        target = math.fsum(w * level for w, level in zip(weights, self._levels, strict=True)) / math.fsum(weights)
        if self._all_levels[action] <= -FIRM_BRAKE:  # unsure how hard to brake: the harder
            target = min(target, self._all_levels[action])
        if self.deadband > 0.0 or self.smoothing < 1.0:
            if controls is None:
                raise ValueError("the deadband and the smoothing read the held force from the controls; none were given")
            held = float(controls[-1][0])
            if target > -FIRM_BRAKE:
                target = held if abs(target - held) <= self.deadband else held + self.smoothing * (target - held)
        return Decision(action, target)


def transfer_weights(src: nn.Module | dict[str, torch.Tensor], dst: nn.Module) -> list[str]:
    """Start ``dst`` from ``src`` where their shapes allow (fine-tuning across action types).

    A tensor of the same shape is copied. A weight that is wider in ``dst`` only in its
    last dimension (the first fully connected layer, when controls join the input) gets
    ``src``'s columns and zeros for the new ones, so ``dst`` starts by computing ``src``'s
    features. Anything else (the output layer of another action set) keeps its
    initialisation.

    Returns:
        The names of the tensors left as initialised.
    """
    src_state, kept = (src if isinstance(src, dict) else src.state_dict()), []
    with torch.no_grad():
        for name, t in dst.state_dict().items():
            s = src_state.get(name)
            if s is not None and s.shape == t.shape:
                t.copy_(s)
            elif s is not None and s.dim() == t.dim() and s.shape[:-1] == t.shape[:-1] and s.shape[-1] < t.shape[-1]:
                t.zero_()
                t[..., : s.shape[-1]] = s
            else:
                kept.append(name)
    return kept


def linear_schedule(start_e: float, end_e: float, duration: int, t: int) -> float:
    """ε at step ``t``: linear from ``start_e`` to ``end_e`` over ``duration`` steps."""
    slope = (end_e - start_e) / duration
    return max(slope * t + start_e, end_e) if end_e < start_e else min(slope * t + start_e, end_e)
