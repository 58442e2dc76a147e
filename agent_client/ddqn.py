"""Double DQN from pixels for vision-based ACC (Wei et al. 2019), in one file.

Read top to bottom, as CleanRL's ``dqn_atari.py``: the config, the network
(the paper's Figure 4), the ε schedule, the replay memory, the Double-DQN target,
checkpoints, evaluation, and the training loop. ``vacc train`` only fills in
:class:`Config` and calls :func:`train`; ``vacc drive --controller ddqn`` uses
:class:`DDQNController`.

The network sees 8 stacked preprocessed camera frames and the 8 matching host
speeds, nothing else: the gap feeds only the reward. Training talks to real
simulator server processes over UDP through :class:`agent_client.env.VisionACCEnv`.

Run folder ``runs/<name>/``:

* ``config.json``: the :class:`Config`;
* ``scalars.csv``: ``step,name,value,wall_s`` rows, names grouped as
  ``charts/``, ``losses/``, ``eval/`` (TensorBoard events too if installed);
* ``latest.pt``: the full training state (weights, target, optimizer, step, RNG
  states), written at episode ends so that a resumed run continues exactly;
* ``replay-<step>.npz``: the replay memory that goes with ``latest.pt`` (which
  names it); the previous one is deleted only after ``latest.pt`` is replaced, so a
  kill at any moment leaves a resumable pair;
* ``best.pt``: policy-only checkpoint (< 5 MB) with the best evaluation so far.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import random
import sys
import time
import zipfile
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W, ZOOMS, preprocess
from agent_client.stacker import FrameStacker

__all__ = [
    "Config",
    "QNetwork",
    "linear_schedule",
    "ReplayMemory",
    "double_dqn_target",
    "dqn_update",
    "save_policy",
    "load_policy",
    "DDQNController",
    "eval_episode",
    "evaluate",
    "train",
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "N_ACTIONS",
    "FORCES",
]

N_ACTIONS = 21
FORCES = np.round(np.linspace(-1.0, 1.0, N_ACTIONS), 1)  # u of action a: -1 + 0.1 a
CHECKPOINT_FORMAT = "vacc-ddqn"
CHECKPOINT_VERSION = 1
DESIRED_GAP = 55.0  # [m] the paper's gap target for RMSE
SESSION_TIMEOUT = 3600.0  # [s] spawned training servers keep an idle session this long


# --------------------------------------------------------------------------- config


@dataclass(frozen=True)
class Config:
    """Every setting of a training run. The CLI only fills this in."""

    reward: str = "gap"
    """Table 1 reward: "gap" (gap term only) or "force" (gap + force terms)."""
    scenario: str = "ice"
    """Simulator scenario: "ice" (eq. 7 lead trajectories) or "ev" (real traces)."""
    total_steps: int = 200_000
    """Environment steps (control periods of 0.1 s) to train for."""
    seed: int = 1
    """Seeds numpy, torch, python random and the stream of episode seeds."""
    learning_rate: float = 1e-4
    """Adam step size."""
    adam_eps: float = 1.5e-4
    """Adam epsilon (Dopamine/CleanRL value for DQN)."""
    buffer_size: int = 100_000
    """Replay memory capacity in transitions (one 105x150 frame each: 1.6 GB at 1e5)."""
    gamma: float = 0.99
    """Discount per control period (0.99 at 0.1 s: a horizon of about 10 s)."""
    target_sync_every: int = 2_000
    """Steps between copies of the online network into the target network."""
    batch_size: int = 32
    """Transitions per gradient step."""
    start_e: float = 1.0
    """ε at step 0."""
    end_e: float = 0.05
    """ε after ``exploration_steps``."""
    exploration_steps: int = 60_000
    """Steps over which ε falls linearly (absolute, so a resumed run keeps its schedule)."""
    learning_starts: int = 5_000
    """Steps of acting before the first gradient step."""
    train_every: int = 4
    """Environment steps per gradient step."""
    max_grad_norm: float = 10.0
    """Gradient norm clip."""
    n_step: int = 1
    """Steps of real rewards before bootstrapping (n-step return, cut at episode ends)."""
    absorbing_terminal: bool = True
    """Value a termination (collision, gap > 300 m) as its reward forever, r / (1 - γ),
    instead of 0: with Table 1's rewards, 0 would make crashing or dropping back past
    300 m look better than a long stretch of small negative rewards."""
    frame_stack: int = 8
    """Frames (and host speeds) per observation (paper: 8)."""
    stack_stride: int = 2
    """Control steps between stacked frames (2: the stack spans 1.4 s)."""
    speed_scale: float = 30.0
    """[m/s] host speeds are divided by this before the network."""
    zoom: int = 1
    """Camera window: 1, the paper's (200x200 gray, the 400x400 camera halved); 2, the
    same 105x150 window around the horizon at full resolution (400x400 gray): the lead
    at 55 m is twice as wide in pixels. Checkpoints record it."""
    episode_seconds: float | None = 60.0
    """[s] training episodes are truncated here (None: the trajectory's 240 s)."""
    eval_every: int = 25_000
    """Steps between evaluations on the test trajectories (0: only at the end)."""
    eval_trajectories: tuple[str, ...] = ("test-1", "test-2", "test-3", "test-4")
    """Trajectories of the periodic evaluation, which picks ``best.pt``: "test-N" (seed 0,
    as ``vacc drive`` uses) or "random:S" (a held-out selection set; :func:`eval_episode`);
    empty: none."""
    eval_seconds: float | None = None
    """[s] evaluation episode length (None: the whole 240 s test trajectory)."""
    checkpoint_every: int = 10_000
    """Steps between full checkpoints (taken at the next episode end)."""
    init_from: str | None = None
    """A policy checkpoint whose weights start the run (fine-tuning, e.g. force from gap);
    None: random initial weights."""
    torch_threads: int = 1
    """CPU threads for torch (the machine is shared)."""
    cuda: bool = True
    """Use CUDA when it is available."""
    log_every: int = 500
    """Steps between loss/Q scalars."""
    servers: int = 1
    """Simulator servers, each with its own acting client, feeding one learner. 1: the
    single-stream loop of :func:`train`; more: :mod:`agent_client.distributed`."""
    weight_sync_every: int = 20
    """(servers > 1) gradient steps between broadcasts of the learner's weights to the
    actors (M): actors act with a policy up to M updates old, plus one batch in flight."""
    actor_batch: int = 50
    """(servers > 1) transitions an actor collects per delivery to the learner."""

    def __post_init__(self) -> None:
        from agent_client.rewards import REWARDS

        if self.reward not in REWARDS:
            raise ValueError(f"reward {self.reward!r} is not one of {sorted(REWARDS)}")
        if self.scenario not in ("ice", "ev"):
            raise ValueError(f"scenario {self.scenario!r} is not 'ice' or 'ev'")
        for name in ("total_steps", "n_step", "buffer_size", "batch_size", "train_every", "target_sync_every", "frame_stack", "stack_stride", "servers", "weight_sync_every", "actor_batch"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError("gamma must be in [0, 1)")
        if self.zoom not in ZOOMS:
            raise ValueError(f"zoom must be one of {ZOOMS}")
        for name in self.eval_trajectories:
            eval_episode(name)  # a typo fails here, not at the first evaluation hours later


# -------------------------------------------------------------------------- network


class QNetwork(nn.Module):
    """The paper's Figure 4, scaled to a 2-core CPU.

    Convolutions over the frame stack (frames as channels); the host-speed sequence
    joins at the fully connected layers; 21 Q-values out.

    conv 5x5/4 (16) -> conv 4x4/2 (32) -> conv 3x3/2 (64) -> 2560 features
    [2560 features, 8 speeds / speed_scale] -> fc 256 -> fc 21

    About 693 k parameters (2.8 MB as float32). The first layer is a 5x5 kernel at
    stride 4 rather than Atari's 8x8: on one CPU thread it cut a batch-32 update
    from about 80 ms to 58 ms and the batch-1 forward by about 15 %.

    The forward pass takes frames and speeds only: there is no way to give it the gap.
    """

    def __init__(self, frame_stack: int = 8, n_actions: int = N_ACTIONS, speed_scale: float = 30.0):
        super().__init__()
        self.speed_scale = speed_scale
        self.conv = nn.Sequential(
            nn.Conv2d(frame_stack, 16, 5, stride=4),
            nn.ReLU(),
            nn.Conv2d(16, 32, 4, stride=2),
            nn.ReLU(),
            nn.Conv2d(32, 64, 3, stride=2),
            nn.ReLU(),
            nn.Flatten(),
        )
        with torch.no_grad():
            n_conv = self.conv(torch.zeros(1, frame_stack, FRAME_H, FRAME_W)).shape[1]
        self.fc = nn.Sequential(nn.Linear(n_conv + frame_stack, 256), nn.ReLU(), nn.Linear(256, n_actions))

    def forward(self, frames: torch.Tensor, speeds: torch.Tensor) -> torch.Tensor:
        """Q-values.

        Args:
            frames: uint8 ``[B, frame_stack, 105, 150]``.
            speeds: host speeds [m/s], ``[B, frame_stack]``.

        Returns:
            ``[B, 21]`` Q-values, one per force level -1.0 .. 1.0.
        """
        x = self.conv(frames.float() / 255.0)  # [B, 2560]
        v = speeds.float() / self.speed_scale  # [B, S]
        return self.fc(torch.cat([x, v], dim=1))  # [B, A]


def linear_schedule(start_e: float, end_e: float, duration: int, t: int) -> float:
    """ε at step ``t``: linear from ``start_e`` to ``end_e`` over ``duration`` steps."""
    slope = (end_e - start_e) / duration
    return max(slope * t + start_e, end_e) if end_e < start_e else min(slope * t + start_e, end_e)


# -------------------------------------------------------------------- replay memory


class ReplayMemory:
    """Stores each camera frame once; rebuilds the stacks when sampling.

    Slot ``i`` holds one observation's newest frame and host speed, its step in the
    episode, and, once the agent has acted on it, the action, reward and the
    ``terminated``/``truncated`` flags of the transition to slot ``i + 1``. The last
    observation of an episode has no action and is never sampled as a start. Stacks
    are rebuilt exactly as :class:`FrameStacker` builds them (the oldest available
    pick repeated at an episode start). Indices are absolute; slot ``i`` lives at
    ``i % capacity``, and a sample is valid only if every frame it needs is still
    in memory.

    Args:
        capacity: slots (about one per transition).
        frame_stack, stack_stride: as the env's.
    """

    def __init__(self, capacity: int, frame_stack: int = 8, stack_stride: int = 1, frame_shape: tuple[int, int] = (FRAME_H, FRAME_W)):
        self.capacity, self.frame_stack, self.stack_stride = capacity, frame_stack, stack_stride
        self.frames = np.zeros((capacity, *frame_shape), np.uint8)
        self.speeds = np.zeros(capacity, np.float32)  # [m/s]
        self.pos = np.zeros(capacity, np.int32)  # step of the slot in its episode
        self.actions = np.zeros(capacity, np.uint8)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.bool_)
        self.truncated = np.zeros(capacity, np.bool_)
        self.has_next = np.zeros(capacity, np.bool_)  # slot i + 1 is this episode's next obs
        self.total = 0  # slots ever written
        self.transitions = 0  # transitions ever added

    def __len__(self) -> int:
        return min(self.total, self.capacity)

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return sum(a.nbytes for a in self._arrays().values())

    def _arrays(self) -> dict[str, np.ndarray]:
        names = ("frames", "speeds", "pos", "actions", "rewards", "terminated", "truncated", "has_next")
        return {n: getattr(self, n) for n in names}

    def _write(self, frame: np.ndarray, speed: float, pos: int) -> None:
        j = self.total % self.capacity
        self.frames[j] = frame
        self.speeds[j] = speed
        self.pos[j] = pos
        self.has_next[j] = False
        self.terminated[j] = self.truncated[j] = False
        self.total += 1

    def start(self, obs: dict[str, np.ndarray]) -> None:
        """Begin an episode with its first observation."""
        self._write(obs["frames"][-1], float(obs["speeds"][-1]), 0)

    def add(self, action: int, reward: float, terminated: bool, truncated: bool, next_obs: dict[str, np.ndarray]) -> None:
        """Record the transition from the newest slot, and the next observation."""
        assert self.total > 0, "start() an episode first"
        j = (self.total - 1) % self.capacity
        self.actions[j], self.rewards[j] = action, reward
        self.terminated[j], self.truncated[j] = terminated, truncated
        self.has_next[j] = True
        self._write(next_obs["frames"][-1], float(next_obs["speeds"][-1]), int(self.pos[j]) + 1)
        self.transitions += 1

    def _stack_index(self, idx: np.ndarray) -> np.ndarray:
        """Absolute slot indices ``[B, S]`` of the stacks ending at ``idx`` ``[B]``."""
        s, k = self.stack_stride, self.frame_stack
        back = np.arange(k - 1, -1, -1)[None, :]  # [1, S]: picks back from the newest
        limit = (self.pos[idx % self.capacity] // s)[:, None]  # [B, 1]: picks back available
        return idx[:, None] - s * np.minimum(back, limit)  # [B, S]

    def stack(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Observation stacks ending at absolute slots ``idx``: frames ``[B, S, H, W]``, speeds ``[B, S]``."""
        j = self._stack_index(np.asarray(idx, np.int64)) % self.capacity
        return self.frames[j], self.speeds[j]

    def _valid(self, idx: np.ndarray) -> np.ndarray:
        oldest = self.total - self.capacity
        j = idx % self.capacity
        s, k = self.stack_stride, self.frame_stack
        # The next observation's stack can reach one frame further back than this one's.
        first = np.minimum(idx - s * np.minimum(k - 1, self.pos[j] // s), idx + 1 - s * np.minimum(k - 1, (self.pos[j] + 1) // s))
        return self.has_next[j] & (idx + 1 < self.total) & (first >= oldest)

    def _n_step(self, idx: np.ndarray, n: int, gamma: float) -> dict[str, np.ndarray]:
        """n-step returns from valid starts ``idx`` ``[B]``, stopping at episode ends."""
        B = len(idx)
        returns = np.zeros(B, np.float64)
        discounts = np.ones(B, np.float64)  # γ^m
        m = np.zeros(B, np.int64)  # real rewards summed
        last_reward = np.zeros(B, np.float32)
        terminated = np.zeros(B, np.bool_)
        truncated = np.zeros(B, np.bool_)
        alive = np.ones(B, np.bool_)
        for k in range(n):
            i = idx + k
            j = i % self.capacity
            ok = alive & self.has_next[j] & (i + 1 < self.total)
            returns += np.where(ok, discounts * self.rewards[j], 0.0)
            last_reward = np.where(ok, self.rewards[j], last_reward)
            terminated |= ok & self.terminated[j]
            truncated |= ok & self.truncated[j]
            discounts = np.where(ok, discounts * gamma, discounts)
            m += ok
            alive = ok & ~self.terminated[j] & ~self.truncated[j]
        return {"returns": returns, "discounts": discounts, "m": m, "last_reward": last_reward, "terminated": terminated, "truncated": truncated}

    def sample(self, batch_size: int, rng: np.random.Generator, n_step: int = 1, gamma: float = 0.99) -> dict[str, np.ndarray]:
        """A uniform batch of valid transitions, with n-step returns.

        Returns:
            ``indices`` ``[B]`` (absolute slots), ``frames`` ``[B, S, H, W]`` uint8,
            ``speeds`` ``[B, S]``, ``actions`` ``[B]``, ``rewards`` ``[B]`` (one step),
            ``returns`` ``[B]`` (Σ γ^k r over up to ``n_step`` steps), ``discounts``
            ``[B]`` (γ^m, m the rewards summed), ``terminal_rewards`` ``[B]`` (the last
            of them), ``terminated``/``truncated`` ``[B]`` (whether the episode ended so
            within those m steps), ``next_frames``, ``next_speeds`` (m steps on).
        """
        lo = max(0, self.total - self.capacity)
        picked: list[np.ndarray] = []
        got = 0
        for _ in range(1000):  # rejection sampling; almost every slot is valid
            cand = rng.integers(lo, self.total, size=2 * batch_size)
            cand = cand[self._valid(cand)]
            if n_step > 1:  # the stack m steps on may reach a frame further back
                m = self._n_step(cand, n_step, gamma)["m"]
                last = cand + m
                back = self.stack_stride * np.minimum(self.frame_stack - 1, self.pos[last % self.capacity] // self.stack_stride)
                cand = cand[last - back >= self.total - self.capacity]
            picked.append(cand)
            got += len(cand)
            if got >= batch_size:
                break
        else:
            raise RuntimeError("replay memory holds no complete transition")
        idx = np.concatenate(picked)[:batch_size]
        j = idx % self.capacity
        ns = self._n_step(idx, n_step, gamma)
        frames, speeds = self.stack(idx)
        next_frames, next_speeds = self.stack(idx + ns["m"])
        return {
            "indices": idx,
            "frames": frames,
            "speeds": speeds,
            "actions": self.actions[j].astype(np.int64),
            "rewards": self.rewards[j],
            "returns": ns["returns"].astype(np.float32),
            "discounts": ns["discounts"].astype(np.float32),
            "terminal_rewards": ns["last_reward"],
            "terminated": ns["terminated"],
            "truncated": ns["truncated"],
            "next_frames": next_frames,
            "next_speeds": next_speeds,
        }

    def save(self, path: Path, step: int) -> None:
        """Write the memory atomically to ``path`` (.npz), tagged with ``step``."""
        n = len(self)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(
                f,
                **{name: a[:n] for name, a in self._arrays().items()},  # type: ignore[arg-type]  # numpy stubs take ** for allow_pickle
                meta=np.array([self.capacity, self.frame_stack, self.stack_stride, self.total, self.transitions, step], np.int64),
            )
        os.replace(tmp, path)

    def load(self, path: Path) -> int:
        """Restore from :meth:`save`; returns the step it was saved at.

        Raises:
            InputFileError: missing, truncated or not matching this memory's settings.
        """
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = z["meta"]
                if tuple(int(x) for x in meta[:3]) != (self.capacity, self.frame_stack, self.stack_stride):
                    raise InputFileError(
                        f"{path}: replay memory of capacity/stack/stride {tuple(int(x) for x in meta[:3])}, "
                        f"expected {(self.capacity, self.frame_stack, self.stack_stride)}"
                    )
                for name, a in self._arrays().items():
                    data = z[name]
                    a[: len(data)] = data
                self.total, self.transitions = int(meta[3]), int(meta[4])
                return int(meta[5])
        except InputFileError:
            raise
        except FileNotFoundError:
            raise InputFileError(f"{path}: replay memory file not found") from None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise InputFileError(f"{path}: unreadable replay memory ({type(exc).__name__}: {exc})") from None


# ---------------------------------------------------------------- Double-DQN target


def double_dqn_target(
    returns: torch.Tensor,
    terminated: torch.Tensor,
    next_q_online: torch.Tensor,
    next_q_target: torch.Tensor,
    discounts: torch.Tensor,
    terminal_values: torch.Tensor,
) -> torch.Tensor:
    """TD target y = G + γ^m Q_target(s', argmax_a Q_online(s', a)), cut at terminations.

    The online network picks the next action, the target network scores it.
    Truncated transitions (time limit) bootstrap like any other; only ``terminated``
    ones do not: they take ``terminal_values`` instead (0, or the terminal reward
    forever with :attr:`Config.absorbing_terminal`). One-step: G = r, γ^m = γ.

    Args:
        returns: ``[B]`` G = Σ_{k<m} γ^k r_k.
        terminated: ``[B]`` bool, the episode terminated within the m steps.
        next_q_online: ``[B, A]`` online Q-values of the observations m steps on.
        next_q_target: ``[B, A]`` target Q-values of the same.
        discounts: ``[B]`` γ^m.
        terminal_values: ``[B]`` the value after a termination.

    Returns:
        ``[B]`` targets.
    """
    next_actions = next_q_online.argmax(dim=1, keepdim=True)  # [B, 1]: online net picks
    next_values = next_q_target.gather(1, next_actions).squeeze(1)  # [B]: target net scores
    done = terminated.float()  # [B]
    bootstrap = (1.0 - done) * next_values + done * terminal_values  # [B]
    return returns + discounts * bootstrap  # [B]


def dqn_update(
    q: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer, b: dict[str, np.ndarray], cfg: Config, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor]:
    """One Double-DQN gradient step on a replay batch (:meth:`ReplayMemory.sample`).

    Returns:
        The Huber loss (scalar) and the online Q-values of the taken actions ``[B]``.
    """
    t = {k: torch.from_numpy(v).to(device) for k, v in b.items() if k != "indices"}
    with torch.no_grad():
        next_q_online = q(t["next_frames"], t["next_speeds"])  # [B, A]
        next_q_target = target(t["next_frames"], t["next_speeds"])  # [B, A]
        # after a termination: the terminal reward forever, r / (1 - γ), or 0
        terminal_values = t["terminal_rewards"] / (1.0 - cfg.gamma) * float(cfg.absorbing_terminal)  # [B]
        td_target = double_dqn_target(
            t["returns"], t["terminated"], next_q_online, next_q_target, t["discounts"], terminal_values
        )  # [B]
    q_taken = q(t["frames"], t["speeds"]).gather(1, t["actions"][:, None]).squeeze(1)  # [B]
    loss = F.smooth_l1_loss(q_taken, td_target)  # Huber
    optimizer.zero_grad()
    loss.backward()
    nn.utils.clip_grad_norm_(q.parameters(), cfg.max_grad_norm)
    optimizer.step()
    return loss, q_taken


# ---------------------------------------------------------------------- checkpoints


def _atomic_save(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def save_policy(q: QNetwork, cfg: Config, path: str | Path, extra: dict[str, Any] | None = None) -> None:
    """Write a policy-only checkpoint (weights + settings), atomically."""
    _atomic_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "kind": "policy",
            "config": _config_dict(cfg),
            "model": {k: v.detach().cpu() for k, v in q.state_dict().items()},
            "extra": extra or {},
        },
        Path(path),
    )


def _read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and check a checkpoint's envelope.

    Raises:
        InputFileError: missing, truncated, not a checkpoint, or another version.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: checkpoint file not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch.load raises many types on corrupt bytes (even IndexError)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise InputFileError(f"{path}: not a readable checkpoint, truncated or corrupt ({type(exc).__name__}: {first[:200]})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(f"{path}: not a vacc DDQN checkpoint (no format tag {CHECKPOINT_FORMAT!r})")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise InputFileError(f"{path}: checkpoint version {ckpt.get('version')!r}, this vacc reads version {CHECKPOINT_VERSION}")
    if not isinstance(ckpt.get("config"), dict) or not isinstance(ckpt.get("model"), dict):
        raise InputFileError(f"{path}: checkpoint lacks its config or model weights")
    return ckpt


def _config_dict(cfg: Config) -> dict[str, Any]:
    d = dataclasses.asdict(cfg)
    d["eval_trajectories"] = list(cfg.eval_trajectories)
    return d


def _config_from(d: dict[str, Any], path: str | Path) -> Config:
    names = {f.name for f in dataclasses.fields(Config)}
    known = {k: v for k, v in d.items() if k in names}
    if "eval_trajectories" in known:
        known["eval_trajectories"] = tuple(known["eval_trajectories"])
    try:
        return Config(**known)
    except (TypeError, ValueError) as exc:
        raise InputFileError(f"{path}: bad config in checkpoint: {exc}") from None


def _load_weights(module: nn.Module, state: dict[str, Any], path: str | Path, what: str = "model") -> None:
    try:
        module.load_state_dict(state)
    except (RuntimeError, KeyError, TypeError) as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        detail = "; ".join(lines[1:4]) if len(lines) > 1 else (lines[0] if lines else "")
        raise InputFileError(f"{path}: {what} weights do not fit the network (wrong shape or layers): {detail[:300]}") from None


def load_policy(path: str | Path, device: str | torch.device = "cpu") -> tuple[QNetwork, Config]:
    """Load the Q-network of a policy or full training checkpoint, in eval mode.

    Raises:
        InputFileError: missing, truncated, wrong format/version, or wrong shapes.
    """
    ckpt = _read_checkpoint(path)
    cfg = _config_from(ckpt["config"], path)
    q = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale)
    _load_weights(q, ckpt["model"], path)
    return q.to(device).eval(), cfg


# ------------------------------------------------------------------------ inference


class DDQNController:
    """Greedy DDQN driver on raw session observations (for ``vacc drive``).

    Keeps its own frame/speed stack with the env's :class:`FrameStacker`, so it sees
    exactly what the network saw in training. Uses the camera image and the host
    speed of the observation only.

    Args:
        q: the Q-network.
        cfg: its config (stack size and stride).
    """

    name = "ddqn"

    def __init__(self, q: QNetwork, cfg: Config):
        self.q, self.cfg = q.eval(), cfg
        self.device = next(q.parameters()).device
        self.stacker = FrameStacker(cfg.frame_stack, cfg.stack_stride)

    @classmethod
    def from_checkpoint(cls, path: str | Path) -> DDQNController:
        """Load from a checkpoint.

        Raises:
            InputFileError: see :func:`load_policy`.
        """
        return cls(*load_policy(path))

    def reset(self) -> None:
        """Forget the previous episode's frames."""
        self.stacker.reset()

    def act(self, stacked: dict[str, np.ndarray]) -> int:
        """Greedy action index for a stacked observation (frames + speeds only)."""
        with torch.inference_mode():
            frames = torch.from_numpy(stacked["frames"]).to(self.device).unsqueeze(0)  # [1, S, H, W]
            speeds = torch.from_numpy(stacked["speeds"]).to(self.device).unsqueeze(0)  # [1, S]
            return int(self.q(frames, speeds).argmax(dim=1).item())

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force u in [-1, 1] for a session observation carrying a gray/RGB image."""
        from agent_client.session import Session

        image = Session.image(obs)
        if image is None:
            raise ValueError("the ddqn controller needs camera images; open the session with image_format='gray'")
        stacked = self.stacker.push(preprocess(image, self.cfg.zoom), float(obs["v_host"]))
        return float(FORCES[self.act(stacked)])


# ----------------------------------------------------------------------- evaluation


TEST_TRAJECTORIES = ("test-1", "test-2", "test-3", "test-4")


def eval_episode(name: str) -> tuple[str, int]:
    """An evaluation trajectory's name to (server trajectory, episode seed).

    "test-N" is a test trajectory from seed 0's start, as ``vacc drive`` drives it.
    "random:S" is the random trajectory (and start, traffic, light) of episode seed S,
    the one ``vacc drive --trajectory random --seed S`` drives: a selection set held out
    from the test set. Training episodes draw their seeds from the run's RNG over
    [0, 2^31), so a small S is, in practice, never a training episode.

    Raises:
        ValueError: any other name.
    """
    if name in TEST_TRAJECTORIES:
        return name, 0
    kind, _, seed = name.partition(":")
    if kind == "random" and seed.isdigit():
        return "random", int(seed)
    raise ValueError(f"evaluation trajectory {name!r} is not one of {', '.join(TEST_TRAJECTORIES)} or random:SEED (e.g. random:101)")


def evaluate(q: QNetwork, env: Any, trajectories: tuple[str, ...]) -> list[dict[str, Any]]:
    """Greedy episodes; gap RMSE against 55 m and collisions.

    Args:
        q: the Q-network.
        env: a :class:`VisionACCEnv` of the scenario.
        trajectories: names for :func:`eval_episode`, e.g. ("test-1", ..., "test-4")
            or ("random:101", "random:102").

    Returns:
        One dict per trajectory: trajectory (its name), gap_rmse_m, collision, steps, reason.
    """
    device = next(q.parameters()).device
    results = []
    for trajectory in trajectories:
        server_trajectory, seed = eval_episode(trajectory)
        obs, info = env.reset(options={"seed": seed, "trajectory": server_trajectory})
        gaps, collision, steps = [info["gap"]], bool(info["collision"]), 0
        done = False
        while not done:
            with torch.inference_mode():
                qv = q(torch.from_numpy(obs["frames"]).to(device)[None], torch.from_numpy(obs["speeds"]).to(device)[None])
            obs, _, terminated, truncated, info = env.step(int(qv.argmax(dim=1).item()))
            gaps.append(info["gap"])
            collision = collision or bool(info["collision"])
            steps += 1
            done = terminated or truncated
        g = np.asarray(gaps)
        results.append(
            {
                "trajectory": trajectory,
                "gap_rmse_m": float(np.sqrt(np.mean((g - DESIRED_GAP) ** 2))),
                "collision": collision,
                "steps": steps,
                "reason": info["reason"],
            }
        )
    return results


# --------------------------------------------------------------------------- logging


class ScalarLog:
    """``scalars.csv`` (``step,name,value,wall_s``), plus TensorBoard if installed."""

    def __init__(self, run_dir: Path, resume_step: int | None = None):
        path = run_dir / "scalars.csv"
        if resume_step is not None and path.exists():  # drop rows the resumed run will redo
            with open(path, newline="") as f:
                rows = [r for r in csv.reader(f)][1:]
            kept = [r for r in rows if r and int(r[0]) <= resume_step]
            with open(path, "w", newline="") as f:
                csv.writer(f).writerows([["step", "name", "value", "wall_s"], *kept])
            self._file = open(path, "a", newline="")
        else:
            self._file = open(path, "w", newline="")
            self._file.write("step,name,value,wall_s\n")
        self._csv = csv.writer(self._file)
        self._t0 = time.time()
        self._tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(run_dir))
        except ImportError:  # tensorboard is an optional extra
            pass

    def add(self, name: str, value: float, step: int) -> None:
        self._csv.writerow([step, name, f"{value:.6g}", f"{time.time() - self._t0:.1f}"])
        if self._tb is not None:
            self._tb.add_scalar(name, value, step)

    def flush(self) -> None:
        self._file.flush()
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


class Progress:
    """A one-line progress display on stderr: steps, steps/s, ε, recent return."""

    def __init__(self, total: int, enabled: bool = True, period: float = 1.0):
        self.total, self.enabled, self.period = total, enabled, period
        self.tty = sys.stderr.isatty()
        self._last = 0.0
        if enabled and not self.tty:
            self.period = max(period, 30.0)  # a log file gets a line every 30 s

    def update(self, step: int, sps: float, epsilon: float, recent_return: float, force: bool = False, extra: str = "") -> None:
        now = time.monotonic()
        if not self.enabled or (now - self._last < self.period and not force):
            return
        self._last = now
        width = 24
        filled = int(width * step / self.total)
        eta = (self.total - step) / sps if sps > 0 else math.inf
        line = (
            f"[{'#' * filled}{'-' * (width - filled)}] {step}/{self.total} "
            f"{sps:5.0f} steps/s  eps {epsilon:.3f}  return {recent_return:8.2f}  eta {eta / 60:5.1f} min"
        ) + (f"  {extra}" if extra else "")
        sys.stderr.write(("\r" + line) if self.tty else (line + "\n"))
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            sys.stderr.write("\n")


def init_from_policy(q: QNetwork, target: QNetwork, cfg: Config) -> None:
    """Start both networks from ``cfg.init_from`` (fine-tuning), if set.

    Raises:
        InputFileError: a bad checkpoint, or one trained on other frames.
    """
    if cfg.init_from is None:
        return
    init_q, init_cfg = load_policy(cfg.init_from)
    if (init_cfg.frame_stack, init_cfg.stack_stride, init_cfg.speed_scale, init_cfg.zoom) != (cfg.frame_stack, cfg.stack_stride, cfg.speed_scale, cfg.zoom):
        raise InputFileError(f"{cfg.init_from}: trained with another frame stack, stride, speed scale or zoom")
    q.load_state_dict(init_q.state_dict())
    target.load_state_dict(init_q.state_dict())


# Settings a resumed run may change: none of them touches the training RNG or the
# learning (evaluations and checkpoints draw nothing from it), so a run resumed with
# other values stays bit-identical to one that never stopped.
RESUMABLE_CHANGES = ("total_steps", "eval_every", "checkpoint_every", "log_every")


def check_resume_config(ckpt: dict[str, Any], cfg: Config, path: Path) -> None:
    """A resumed run must have the saved run's settings, but for ``RESUMABLE_CHANGES``.

    Raises:
        InputFileError: naming every setting that differs.
    """
    saved = _config_from(ckpt["config"], path)
    if dataclasses.replace(saved, **{k: getattr(cfg, k) for k in RESUMABLE_CHANGES}) != cfg:
        diff = {k: (v, getattr(cfg, k)) for k, v in dataclasses.asdict(saved).items() if k not in RESUMABLE_CHANGES and v != getattr(cfg, k)}
        raise InputFileError(f"{path}: the run was trained with other settings; differences (saved, given): {diff}")


def log_evaluation(log: ScalarLog, results: list[dict[str, Any]], step: int) -> float:
    """Write an evaluation's ``eval/`` scalars; return its score (lower is better).

    Score: fewest failures (a collision, or losing the lead past 300 m), then the
    worst trajectory's RMSE (the target is per trajectory).
    """
    rmse = [r["gap_rmse_m"] for r in results]
    for r in results:
        log.add(f"eval/gap_rmse_m/{r['trajectory']}", r["gap_rmse_m"], step)
    log.add("eval/gap_rmse_m", max(rmse), step)
    log.add("eval/gap_rmse_mean_m", float(np.mean(rmse)), step)
    log.add("eval/collisions", sum(r["collision"] for r in results), step)
    failures = sum(r["collision"] or r["reason"] not in ("end", "") for r in results)
    log.add("eval/failures", failures, step)
    return 1e6 * failures + max(rmse)


# ------------------------------------------------------------------------- training


@dataclass
class _State:
    """What a resumed run needs besides the weights and the replay memory."""

    global_step: int = 0
    episodes: int = 0
    best_score: float = math.inf
    recent_returns: list[float] = field(default_factory=list)


def _save_training(path: Path, q: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer, cfg: Config, state: _State, rng: np.random.Generator, replay: str) -> None:
    _atomic_save(
        {
            "format": CHECKPOINT_FORMAT,
            "replay": replay,
            "version": CHECKPOINT_VERSION,
            "kind": "training",
            "config": _config_dict(cfg),
            "model": q.state_dict(),
            "target": target.state_dict(),
            "optimizer": optimizer.state_dict(),
            "state": dataclasses.asdict(state),
            "rng": {
                "numpy": rng.bit_generator.state,
                "torch": torch.get_rng_state(),
                "python": list(random.getstate()[1]),
                "python_version": random.getstate()[0],
            },
        },
        path,
    )


def train(
    cfg: Config,
    run_dir: str | Path,
    *,
    resume: bool = False,
    progress: bool = True,
    server_args: tuple[str, ...] = (),
    on_eval: Callable[[int, list[dict[str, Any]]], None] | None = None,
) -> dict[str, Any]:
    """Train a DDQN policy against spawned simulator servers; write the run folder.

    Args:
        cfg: the settings (with ``resume``, those of the run being resumed must match
            in everything but ``total_steps``).
        run_dir: ``runs/<name>``.
        resume: continue from ``run_dir/latest.pt`` and the replay file it names.
        progress: show the progress line on stderr.
        server_args: extra ``python -m sim_server`` arguments for the spawned servers.
        on_eval: called with (step, results) after each evaluation.

    Returns:
        Summary: steps, episodes, best score, last evaluation, wall time [s].

    Raises:
        InputFileError: ``resume`` with a missing or bad checkpoint or replay file.
    """
    from agent_client.env import VisionACCEnv  # the env spawns servers; import late

    if cfg.servers != 1:
        raise ValueError(f"train() runs one stream; servers={cfg.servers} needs agent_client.distributed.train_distributed")

    # The training session sits idle through evaluations and replay saves; keep the
    # spawned servers from freeing it (their default is 10 s of silence).
    server_args = ("--session-timeout", str(SESSION_TIMEOUT), *server_args)

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    latest, best_path = run_dir / "latest.pt", run_dir / "best.pt"

    # --- seeding: the one block. Everything random below draws from these. -------
    random.seed(cfg.seed)
    np_rng = np.random.default_rng(cfg.seed)  # ε draws, random actions, replay sampling, episode seeds
    torch.manual_seed(cfg.seed)
    torch.backends.cudnn.deterministic = True
    torch.set_num_threads(cfg.torch_threads)
    device = torch.device("cuda" if cfg.cuda and torch.cuda.is_available() else "cpu")

    q = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale).to(device)
    target = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale).to(device)
    target.load_state_dict(q.state_dict())
    optimizer = torch.optim.Adam(q.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
    memory = ReplayMemory(cfg.buffer_size, cfg.frame_stack, cfg.stack_stride)
    state = _State()

    if not resume:
        init_from_policy(q, target, cfg)
    if resume:
        ckpt = _read_checkpoint(latest)
        if ckpt.get("kind") != "training":
            raise InputFileError(f"{latest}: a policy-only checkpoint cannot be resumed")
        check_resume_config(ckpt, cfg, latest)
        _load_weights(q, ckpt["model"], latest)
        _load_weights(target, ckpt["target"], latest, "target")
        try:
            optimizer.load_state_dict(ckpt["optimizer"])
            state = _State(**ckpt["state"])
            np_rng.bit_generator.state = ckpt["rng"]["numpy"]
            torch.set_rng_state(ckpt["rng"]["torch"])
            random.setstate((ckpt["rng"]["python_version"], tuple(ckpt["rng"]["python"]), None))
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise InputFileError(f"{latest}: incomplete training state ({type(exc).__name__}: {exc})") from None
        replay_path = run_dir / str(ckpt.get("replay", "replay.npz"))
        replay_step = memory.load(replay_path)
        if replay_step != state.global_step:
            raise InputFileError(f"{replay_path}: saved at step {replay_step}, but {latest} is at step {state.global_step}")
    (run_dir / "config.json").write_text(json.dumps(_config_dict(cfg), indent=2) + "\n")

    log = ScalarLog(run_dir, resume_step=state.global_step if resume else None)
    bar = Progress(cfg.total_steps, enabled=progress)
    recent = deque(state.recent_returns, maxlen=20)
    env = VisionACCEnv(
        scenario=cfg.scenario, trajectory="random", reward=cfg.reward, frame_stack=cfg.frame_stack,
        stack_stride=cfg.stack_stride, episode_seconds=cfg.episode_seconds, server_args=server_args, zoom=cfg.zoom,
    )  # fmt: skip
    eval_env: VisionACCEnv | None = None
    last_eval: list[dict[str, Any]] = []
    t_start, steps_at_start = time.perf_counter(), state.global_step
    next_checkpoint = state.global_step + cfg.checkpoint_every
    # On the eval_every grid, so that a resumed run evaluates where it would have.
    next_eval = (state.global_step // cfg.eval_every + 1) * cfg.eval_every if cfg.eval_every > 0 else math.inf
    last_eval_step = -1

    def run_eval() -> None:
        nonlocal eval_env, last_eval
        if eval_env is None:
            eval_env = VisionACCEnv(
                scenario=cfg.scenario, trajectory=eval_episode(cfg.eval_trajectories[0])[0], reward=cfg.reward,
                frame_stack=cfg.frame_stack, stack_stride=cfg.stack_stride,
                episode_seconds=cfg.eval_seconds, server_args=server_args, zoom=cfg.zoom,
            )  # fmt: skip
        q.eval()
        last_eval = evaluate(q, eval_env, cfg.eval_trajectories)
        q.train()
        score = log_evaluation(log, last_eval, state.global_step)
        if score < state.best_score:
            state.best_score = score
            save_policy(q, cfg, best_path, {"step": state.global_step, "eval": last_eval})
        log.flush()
        if on_eval is not None:
            on_eval(state.global_step, last_eval)

    try:
        while state.global_step < cfg.total_steps:
            obs, _ = env.reset(options={"seed": int(np_rng.integers(2**31))})
            memory.start(obs)
            episode_return, episode_len, done = 0.0, 0, False
            while not done and state.global_step < cfg.total_steps:
                epsilon = linear_schedule(cfg.start_e, cfg.end_e, cfg.exploration_steps, state.global_step)
                if np_rng.random() < epsilon:
                    action = int(np_rng.integers(N_ACTIONS))
                else:
                    with torch.no_grad():
                        qv = q(torch.from_numpy(obs["frames"]).to(device)[None], torch.from_numpy(obs["speeds"]).to(device)[None])  # [1, A]
                    action = int(qv.argmax(dim=1).item())
                next_obs, reward, terminated, truncated, _ = env.step(action)
                memory.add(action, reward, terminated, truncated, next_obs)
                obs = next_obs
                episode_return += reward
                episode_len += 1
                done = terminated or truncated
                state.global_step += 1
                step = state.global_step

                if step > cfg.learning_starts and step % cfg.train_every == 0:
                    b = memory.sample(cfg.batch_size, np_rng, cfg.n_step, cfg.gamma)
                    loss, q_taken = dqn_update(q, target, optimizer, b, cfg, device)
                    if step % cfg.log_every < cfg.train_every:
                        log.add("losses/td_loss", loss.item(), step)
                        log.add("losses/q_values", q_taken.mean().item(), step)
                if step % cfg.target_sync_every == 0:
                    target.load_state_dict(q.state_dict())
                sps = (step - steps_at_start) / max(time.perf_counter() - t_start, 1e-9)
                bar.update(step, sps, epsilon, float(np.mean(recent)) if recent else float("nan"))

            if done:  # a whole episode (not one cut by the step budget)
                state.episodes += 1
                recent.append(episode_return)
                log.add("charts/episodic_return", episode_return, state.global_step)
                log.add("charts/episodic_length", episode_len, state.global_step)
                log.add("charts/mean_reward", episode_return / max(episode_len, 1), state.global_step)
                log.add("charts/SPS", sps, state.global_step)
                log.add("charts/epsilon", epsilon, state.global_step)
            finished = state.global_step >= cfg.total_steps
            if cfg.eval_trajectories and (state.global_step >= next_eval or (finished and last_eval_step != state.global_step)):
                run_eval()
                last_eval_step = state.global_step
                while next_eval <= state.global_step:
                    next_eval += cfg.eval_every
            if state.global_step >= next_checkpoint or finished:
                state.recent_returns = list(recent)
                # Replay first, under a new name; then latest.pt, which names it; only
                # then the old replay goes. A kill -9 anywhere leaves a resumable pair.
                replay_name = f"replay-{state.global_step}.npz"
                memory.save(run_dir / replay_name, state.global_step)
                _save_training(latest, q, target, optimizer, cfg, state, np_rng, replay_name)
                for old in [*run_dir.glob("replay-*.npz"), run_dir / "replay.npz"]:
                    if old.name != replay_name and old.exists():
                        old.unlink()
                log.flush()
                next_checkpoint = state.global_step + cfg.checkpoint_every
        bar.update(state.global_step, 0.0, linear_schedule(cfg.start_e, cfg.end_e, cfg.exploration_steps, state.global_step),
                   float(np.mean(recent)) if recent else float("nan"), force=True)  # fmt: skip
    finally:
        bar.close()
        log.close()
        env.close()
        if eval_env is not None:
            eval_env.close()
    return {
        "steps": state.global_step,
        "episodes": state.episodes,
        "best_score": state.best_score,
        "last_eval": last_eval,
        "wall_s": time.perf_counter() - t_start,
        "replay_bytes_per_transition": memory.nbytes / memory.capacity,
    }
