"""Replay memory: each camera frame stored once, stacks rebuilt by array indexing.

Kept apart from the algorithm, as Stable-Baselines3 keeps ``buffers.py``. A sample is a
:class:`ReplaySamples` of torch tensors. The frame stacks of a batch (current and n
steps on) are gathered in one ``index_select`` into a buffer the memory owns, so a
batch costs no allocation: its tensors stay valid until the next ``sample`` call.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W

__all__ = ["ReplayMemory", "ReplaySamples", "SequenceSamples", "StreamReplay", "flat_transitions"]


class ReplaySamples(NamedTuple):
    """A batch of transitions with n-step returns (CPU tensors; B transitions, S frames)."""

    indices: np.ndarray  # [B] absolute slots of the first observations
    frames: torch.Tensor  # [B, S, H, W] uint8
    speeds: torch.Tensor  # [B, S] float32 [m/s]
    controls: torch.Tensor  # [B, S, C] float32 (C = 0 for the paper's action type)
    actions: torch.Tensor  # [B] int64 (float32: the continuous action type's target forces)
    rewards: torch.Tensor  # [B] float32, the first step's reward
    returns: torch.Tensor  # [B] float32, sum of gamma^k r_k over the m steps summed
    discounts: torch.Tensor  # [B] float32, gamma^m
    terminal_rewards: torch.Tensor  # [B] float32, the last reward summed
    terminated: torch.Tensor  # [B] bool, the episode terminated within the m steps
    truncated: torch.Tensor  # [B] bool, ... or was truncated
    next_frames: torch.Tensor  # [B, S, H, W] uint8, m steps on
    next_speeds: torch.Tensor  # [B, S] float32
    next_controls: torch.Tensor  # [B, S, C] float32
    gaps: torch.Tensor  # [B] float32 [m], the first observations' gaps (NaN: a memory without them)
    next_gaps: torch.Tensor  # [B] float32 [m], the gaps one step on (the same episode's next observation)
    lead_stops: torch.Tensor | None = None  # [B] float32 [m], the lead's stopping distance at the first observations (inf: not braking; None: not kept)


class SequenceSamples(NamedTuple):
    """A batch of B replayed sequences of L transitions for a recurrent network (CPU tensors).

    Step k of sequence b is the transition from slot ``indices[b] + k``; ``frames[:, k + 1]``
    is its next observation. A sequence stops at its episode's end: ``mask`` is False from
    there on (those steps repeat the last observation). ``train`` marks the steps whose loss
    counts: past the burn-in, or every step of a sequence that starts its episode (its
    stored state, zeros, is then exact).
    """

    indices: np.ndarray  # [B] absolute slots of the first observations
    states: torch.Tensor  # [B, hidden] float32, the acting network's state before the first observation
    frames: torch.Tensor  # [B, L + 1, S, H, W] uint8
    speeds: torch.Tensor  # [B, L + 1, S] float32 [m/s]
    controls: torch.Tensor  # [B, L + 1, S, C] float32
    actions: torch.Tensor  # [B, L] int64 (float32: the continuous action type's target forces)
    rewards: torch.Tensor  # [B, L] float32
    terminated: torch.Tensor  # [B, L] bool
    truncated: torch.Tensor  # [B, L] bool
    gaps: torch.Tensor  # [B, L] float32 [m] (NaN: a memory without them)
    next_gaps: torch.Tensor  # [B, L] float32 [m]
    mask: torch.Tensor  # [B, L] bool, a transition of the sequence's episode
    train: torch.Tensor  # [B, L] bool, its loss counts


class _Plan(NamedTuple):
    """Which slots a batch (or one stream's share of it) reads."""

    idx: np.ndarray  # [b] absolute start slots
    ns: dict[str, np.ndarray]  # n-step sums (see ReplayMemory._n_step)


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
        frame_shape: (H, W) of a preprocessed frame.
        n_controls: controls per slot (the "steps" action type's force and set speed; 0: none).
        gaps: keep each observation's gap [m] (privileged: the auxiliary gap head's target,
            never part of an observation; ``Config.aux_gap``).
        continuous: store actions as float32 target forces (the continuous action type),
            not uint8 indices.
        state_size: keep with each observation the recurrent network's state before it
            (``[state_size]`` float32; 0: a frame-stack network's memory, none).
        lead_stops: keep the distance [m] the lead needs to stop at its present deceleration
            (privileged, inf where it is not braking; ``Config.emergency`` "stopping").
    """

    def __init__(
        self, capacity: int, frame_stack: int = 8, stack_stride: int = 1, frame_shape: tuple[int, int] = (FRAME_H, FRAME_W),
        n_controls: int = 0, gaps: bool = False, continuous: bool = False, state_size: int = 0, lead_stops: bool = False,
    ):  # fmt: skip
        self.capacity, self.frame_stack, self.stack_stride = capacity, frame_stack, stack_stride
        self.frames = np.zeros((capacity, *frame_shape), np.uint8)
        self.speeds = np.zeros(capacity, np.float32)  # [m/s]
        self.controls = np.zeros((capacity, n_controls), np.float32)
        self.gaps = np.full(capacity if gaps else 0, np.nan, np.float32)  # [m]
        self.lead_stops = np.full(capacity if lead_stops else 0, np.inf, np.float32)  # [m]
        self.pos = np.zeros(capacity, np.int32)  # step of the slot in its episode
        self.actions = np.zeros(capacity, np.float32 if continuous else np.uint8)
        self.rewards = np.zeros(capacity, np.float32)
        self.terminated = np.zeros(capacity, np.bool_)
        self.truncated = np.zeros(capacity, np.bool_)
        self.has_next = np.zeros(capacity, np.bool_)  # slot i + 1 is this episode's next obs
        self.states = np.zeros((capacity if state_size else 0, state_size), np.float32)
        self.total = 0  # slots ever written
        self._warm = 0  # pre-roll frames written for the episode about to start
        self.transitions = 0  # transitions ever added
        self._frames_t = torch.from_numpy(self.frames)  # shares memory: index_select reads it in place
        self._out: torch.Tensor | None = None

    def __len__(self) -> int:
        return min(self.total, self.capacity)

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return sum(a.nbytes for a in self._arrays().values())

    def _arrays(self) -> dict[str, np.ndarray]:
        names: tuple[str, ...] = ("frames", "speeds", "pos", "actions", "rewards", "terminated", "truncated", "has_next")
        if self.controls.shape[1]:  # absent from the paper's memories and their files
            names += ("controls",)
        if len(self.gaps):
            names += ("gaps",)
        if len(self.lead_stops):
            names += ("lead_stops",)
        if len(self.states):
            names += ("states",)
        return {n: getattr(self, n) for n in names}

    def _write(self, obs: dict[str, np.ndarray], pos: int, gap: float = np.nan, state: np.ndarray | None = None, lead_stop: float = np.inf) -> None:
        j = self.total % self.capacity
        self.frames[j] = obs["frames"][-1]
        if len(self.gaps):
            self.gaps[j] = gap
        if len(self.lead_stops):
            self.lead_stops[j] = lead_stop
        if len(self.states):
            if state is None:
                raise ValueError("this memory keeps a recurrent state with each observation; none was given")
            self.states[j] = state
        self.speeds[j] = float(obs["speeds"][-1])
        if self.controls.shape[1]:
            self.controls[j] = obs["controls"][-1]
        self.pos[j] = pos
        self.has_next[j] = False
        self.terminated[j] = self.truncated[j] = False
        self.total += 1

    def warm(self, obs: dict[str, np.ndarray]) -> None:
        """Store a frame of the camera's pre-roll before the episode's first observation:
        the first stacks reach back into it, and it is never a transition's start."""
        self._write(obs, self._warm, state=np.zeros(self.states.shape[1], np.float32) if len(self.states) else None)  # never a start: no state to keep
        self._warm += 1

    def start(self, obs: dict[str, np.ndarray], gap: float = np.nan, state: np.ndarray | None = None, lead_stop: float = np.inf) -> None:
        """Begin an episode with its first observation (after its :meth:`warm` frames, if any),
        its gap [m] and lead's stopping distance [m] in a memory that keeps them, and the
        recurrent state before it in one that keeps those."""
        self._write(obs, self._warm, gap, state, lead_stop)
        self._warm = 0

    def add(self, action: int | float, reward: float, terminated: bool, truncated: bool, next_obs: dict[str, np.ndarray], gap: float = np.nan,
            state: np.ndarray | None = None, lead_stop: float = np.inf) -> None:  # fmt: skip
        """Record the transition from the newest slot, and the next observation (with its gap [m],
        its lead's stopping distance [m] and the recurrent state before it)."""
        assert self.total > 0, "start() an episode first"
        j = (self.total - 1) % self.capacity
        self.actions[j], self.rewards[j] = action, reward
        self.terminated[j], self.truncated[j] = terminated, truncated
        self.has_next[j] = True
        self._write(next_obs, int(self.pos[j]) + 1, gap, state, lead_stop)
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

    def stack_controls(self, idx: np.ndarray) -> np.ndarray:
        """Control stacks ending at absolute slots ``idx``: ``[B, S, C]``."""
        return self.controls[self._stack_index(np.asarray(idx, np.int64)) % self.capacity]

    def _gather(self, idx: np.ndarray, out: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """Frame stacks ending at ``idx`` ``[b]`` into ``out`` ``[b, S, H, W]``; returns their
        speeds ``[b, S]`` and controls ``[b, S, C]``."""
        j = self._stack_index(idx) % self.capacity  # [b, S]
        torch.index_select(self._frames_t, 0, torch.from_numpy(j.reshape(-1)), out=out.view(-1, *self.frames.shape[1:]))
        return self.speeds[j], self.controls[j]

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


    def _plan(self, batch_size: int, rng: np.random.Generator, n_step: int, gamma: float) -> _Plan:
        """Draw ``batch_size`` valid start slots uniformly (rejection sampling) and their n-step sums."""
        lo = max(0, self.total - self.capacity)
        picked: list[np.ndarray] = []
        got = 0
        for _ in range(1000):  # almost every slot is valid
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
        return _Plan(idx, self._n_step(idx, n_step, gamma))

    def sample(self, batch_size: int, rng: np.random.Generator, n_step: int = 1, gamma: float = 0.99) -> ReplaySamples:
        """A uniform batch of valid transitions, with n-step returns (:class:`ReplaySamples`).

        The tensors are valid until the next call (they share this memory's buffer).
        """
        return _assemble([(self, self._plan(batch_size, rng, n_step, gamma))], self._buffer(batch_size))

    def sample_sequences(self, batch_size: int, rng: np.random.Generator, length: int, burn_in: int) -> SequenceSamples:
        """``batch_size`` sequences of up to ``length`` transitions, each starting at a valid
        slot drawn uniformly, with the stored state before it (:class:`SequenceSamples`)."""
        if not len(self.states):
            raise ValueError("sequences need a memory that keeps the recurrent state (state_size > 0)")
        idx = self._plan(batch_size, rng, 1, 1.0).idx  # [B] valid starts
        k = np.arange(length)[None, :]  # [1, L]
        alive = np.ones((len(idx), length), np.bool_)
        for step in range(1, length):  # a transition of the same episode, all of it in memory
            prev, cur = (idx + step - 1) % self.capacity, idx + step
            alive[:, step] = alive[:, step - 1] & ~self.terminated[prev] & ~self.truncated[prev] & self.has_next[cur % self.capacity] & (cur + 1 < self.total)
        reach = alive.sum(axis=1)  # [B] transitions in each sequence (>= 1)
        slots = idx[:, None] + np.minimum(np.arange(length + 1)[None, :], reach[:, None])  # [B, L + 1]: the last observation repeated
        j, jt = slots % self.capacity, slots[:, :-1] % self.capacity
        stacks = self._stack_index(slots.reshape(-1)) % self.capacity  # [B (L + 1), S]
        shape = (len(idx), length + 1, self.frame_stack)
        frames = torch.from_numpy(self.frames[stacks].reshape(*shape, *self.frames.shape[1:]))
        prev = idx - 1  # an episode's first observation follows a slot that has no next (or none at all)
        first = (prev < 0) | ((prev >= self.total - self.capacity) & ~self.has_next[prev % self.capacity])
        train = alive & ((k >= burn_in) | first[:, None])
        gaps = self.gaps[jt] if len(self.gaps) else np.full(jt.shape, np.nan, np.float32)
        next_gaps = self.gaps[j[:, 1:]] if len(self.gaps) else np.full(jt.shape, np.nan, np.float32)
        return SequenceSamples(
            indices=idx, states=torch.from_numpy(self.states[idx % self.capacity]), frames=frames,
            speeds=torch.from_numpy(self.speeds[stacks].reshape(shape)), controls=torch.from_numpy(self.controls[stacks].reshape(*shape, -1)),
            actions=torch.from_numpy(self.actions[jt] if self.actions.dtype == np.float32 else self.actions[jt].astype(np.int64)), rewards=torch.from_numpy(self.rewards[jt]),
            terminated=torch.from_numpy(self.terminated[jt] & alive), truncated=torch.from_numpy(self.truncated[jt] & alive),
            gaps=torch.from_numpy(gaps), next_gaps=torch.from_numpy(next_gaps), mask=torch.from_numpy(alive), train=torch.from_numpy(train),
        )  # fmt: skip

    def _buffer(self, batch_size: int) -> torch.Tensor:
        """The ``[2, B, S, H, W]`` uint8 gather buffer (current and next stacks)."""
        shape = (2, batch_size, self.frame_stack, *self.frames.shape[1:])
        if self._out is None or tuple(self._out.shape) != shape:
            self._out = torch.empty(shape, dtype=torch.uint8)
        return self._out

    def save(self, path: Path, step: int) -> None:
        """Write the memory atomically to ``path`` (.npz), tagged with ``step``.

        Raises:
            CheckpointWriteError: the write failed (e.g. a full disk); no temporary file is left.
        """
        from agent_client.rl.checkpoint import write_atomically

        n = len(self)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(
                    f,
                    **{name: a[:n] for name, a in self._arrays().items()},  # type: ignore[arg-type]  # numpy stubs take ** for allow_pickle
                    meta=np.array([self.capacity, self.frame_stack, self.stack_stride, self.total, self.transitions, step], np.int64),
                )

        write_atomically(path, write)

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


def _assemble(parts: list[tuple[ReplayMemory, _Plan]], buffer: torch.Tensor) -> ReplaySamples:
    """One :class:`ReplaySamples` from the plans of one or more memories, gathered into ``buffer``."""
    speeds, next_speeds, controls, next_controls, gaps, next_gaps, lead_stops, fields = [], [], [], [], [], [], [], []
    start = 0
    for memory, plan in parts:
        end = start + len(plan.idx)
        v, c = memory._gather(plan.idx, buffer[0, start:end])
        speeds.append(v)
        controls.append(c)
        v, c = memory._gather(plan.idx + plan.ns["m"], buffer[1, start:end])
        next_speeds.append(v)
        next_controls.append(c)
        j = plan.idx % memory.capacity
        none = np.full(len(j), np.nan, np.float32)
        gaps.append(memory.gaps[j] if len(memory.gaps) else none)
        next_gaps.append(memory.gaps[(plan.idx + 1) % memory.capacity] if len(memory.gaps) else none)  # a valid start has a next slot
        if len(memory.lead_stops):
            lead_stops.append(memory.lead_stops[j])
        actions = memory.actions[j]
        fields.append((plan.idx, actions if actions.dtype == np.float32 else actions.astype(np.int64), memory.rewards[j], plan.ns))
        start = end
    if lead_stops and len(lead_stops) != len(parts):  # a column for some rows only would misalign the batch
        raise ValueError("replay memories sampled together must all keep the lead stops or none")

    def cat(arrays: list[np.ndarray], dtype: Any = None) -> torch.Tensor:
        a = arrays[0] if len(arrays) == 1 else np.concatenate(arrays)
        return torch.from_numpy(a if dtype is None else a.astype(dtype))

    return ReplaySamples(
        indices=np.concatenate([f[0] for f in fields]),
        frames=buffer[0, :start],
        speeds=cat(speeds),
        controls=cat(controls),
        actions=cat([f[1] for f in fields]),
        rewards=cat([f[2] for f in fields]),
        returns=cat([f[3]["returns"] for f in fields], np.float32),
        discounts=cat([f[3]["discounts"] for f in fields], np.float32),
        terminal_rewards=cat([f[3]["last_reward"] for f in fields]),
        terminated=cat([f[3]["terminated"] for f in fields]),
        truncated=cat([f[3]["truncated"] for f in fields]),
        next_frames=buffer[1, :start],
        next_speeds=cat(next_speeds),
        next_controls=cat(next_controls),
        gaps=cat(gaps),
        next_gaps=cat(next_gaps),
        lead_stops=cat(lead_stops) if lead_stops else None,  # None: no memory keeps them
    )


class StreamReplay:
    """K replay streams, one :class:`ReplayMemory` per actor, sampled as one memory.

    Args:
        buffer_size: split evenly over the ``k`` streams.
        k: streams.
        frame_stack, stack_stride: as the env's.
    """

    def __init__(self, buffer_size: int, k: int, frame_stack: int, stack_stride: int):
        sizes = [buffer_size // k + (i < buffer_size % k) for i in range(k)]
        self.streams = [ReplayMemory(c, frame_stack, stack_stride) for c in sizes]

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.streams)

    @property
    def capacity(self) -> int:
        return sum(m.capacity for m in self.streams)

    def start(self, i: int, frame: np.ndarray, speed: float) -> None:
        """Begin an episode in stream ``i`` with its first frame [105, 150] and host speed [m/s]."""
        self.streams[i].start({"frames": frame[None], "speeds": np.array([speed], np.float32)})

    def add(self, i: int, action: int, reward: float, terminated: bool, truncated: bool, frame: np.ndarray, speed: float) -> None:
        """Record a transition of stream ``i`` and its next frame and speed."""
        self.streams[i].add(action, reward, terminated, truncated, {"frames": frame[None], "speeds": np.array([speed], np.float32)})

    def sample(self, batch_size: int, rng: np.random.Generator, n_step: int = 1, gamma: float = 0.99) -> ReplaySamples:
        """A batch uniform over every stored slot of every stream (see :meth:`ReplayMemory.sample`)."""
        sizes = np.array([len(m) if m.transitions > 0 else 0 for m in self.streams], np.float64)
        if sizes.sum() == 0:
            raise RuntimeError("replay memory holds no complete transition")
        counts = rng.multinomial(batch_size, sizes / sizes.sum())
        parts = [(m, m._plan(int(c), rng, n_step, gamma)) for m, c in zip(self.streams, counts, strict=True) if c > 0]
        return _assemble(parts, self.streams[0]._buffer(batch_size))

    def file_names(self, step: int) -> list[str]:
        """The files :meth:`save` writes at ``step``: ``replay-<step>-<i>.npz``."""
        return [f"replay-{step}-{i}.npz" for i in range(len(self.streams))]

    def save(self, run_dir: Path, step: int) -> list[str]:
        """Write every stream as ``replay-<step>-<i>.npz``; returns the names."""
        names = self.file_names(step)
        for m, name in zip(self.streams, names, strict=True):
            m.save(run_dir / name, step)
        return names

    def load(self, run_dir: Path, names: list[str], step: int) -> None:
        """Restore the streams written by :meth:`save` at ``step``.

        Raises:
            InputFileError: a file missing, unreadable, of another layout or another step.
        """
        if len(names) != len(self.streams):
            raise InputFileError(f"{run_dir}: the checkpoint names {len(names)} replay streams, the run has {len(self.streams)}")
        for m, name in zip(self.streams, names, strict=True):
            saved = m.load(run_dir / name)
            if saved != step:
                raise InputFileError(f"{run_dir / name}: saved at step {saved}, but latest.pt is at step {step}")


def flat_transitions(seq: SequenceSamples, gamma: float) -> ReplaySamples:
    """The trained steps of replayed sequences as one batch of one-step transitions, for the
    loss terms (no frames: the recurrent update has unrolled them already)."""
    keep = seq.train
    none = torch.empty(0)
    rewards = seq.rewards[keep]
    return ReplaySamples(
        indices=seq.indices, frames=none, speeds=seq.speeds[:, :-1][keep], controls=seq.controls[:, :-1][keep], actions=seq.actions[keep],
        rewards=rewards, returns=rewards, discounts=torch.full_like(rewards, gamma), terminal_rewards=rewards,
        terminated=seq.terminated[keep], truncated=seq.truncated[keep], next_frames=none, next_speeds=seq.speeds[:, 1:][keep],
        next_controls=seq.controls[:, 1:][keep], gaps=seq.gaps[keep], next_gaps=seq.next_gaps[keep],
    )  # fmt: skip
