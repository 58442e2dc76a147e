"""Many simulator servers, one learner: Double DQN fed by K acting streams (issue #10).

``vacc train --servers K`` runs the K actors as local processes; ``vacc train --ray
--servers K`` runs them as Ray actors, on this machine or across a cluster. Both use
the same :class:`StreamActor` and the same learner loop, :func:`train_distributed`.
``--servers 1`` without ``--ray`` stays on :func:`agent_client.ddqn.train`, the
single-stream loop whose resume is bit-exact.

::

    actor i (process or Ray actor, 1 CPU)              learner (this process)
    ┌────────────────────────────────────────┐ batches ┌───────────────────────────────┐
    │ sim_server on 127.0.0.1 of its node    │ ──────> │ K ReplayMemory streams        │
    │ VisionACCEnv, CPU copy of the QNetwork │         │ QNetwork (GPU if any), target │
    │ ε-greedy; episode k seeded (seed, i, k)│ <────── │ Adam, evaluation, checkpoints │
    └────────────────────────────────────────┘ weights └───────────────────────────────┘
                                                every M updates

Decisions:

* **What travels.** An actor sends batches of ``Config.actor_batch`` (50)
  transitions. A record is one new preprocessed 105x150 uint8 frame (15,750 B) with
  its host speed and, for a transition, the action, reward, ``terminated`` and
  ``truncated`` that led to it; the first record of an episode is its start. The
  8-frame stack is never sent: the learner's replay rebuilds it. About 15.8 KB per
  transition on the wire.
* **Replay.** A :class:`ReplayMemory` holds one contiguous stream of episodes, so
  there is one per actor (``buffer_size`` split evenly; :class:`StreamReplay`). A
  batch draws its per-stream counts from a multinomial in proportion to the streams'
  sizes and samples each stream uniformly: uniform over every stored slot. Bytes per
  transition are ReplayMemory's (1.001x one frame).
* **Update-to-data ratio** as the single stream: one gradient step per
  ``train_every`` transitions received past ``learning_starts``, the target network
  synced on the same env-step grid. The learner does the updates it owes before it
  takes more data; actors block when their outbox is full (local: one batch queued,
  one being sent; Ray: two calls in flight), so a slow learner slows the actors
  instead of the ratio drifting. At the start the learner waits (up to
  ``STARTUP_TIMEOUT``) until every actor has its server, so none starts far behind.
* **Weights: M and staleness.** The learner publishes its weights every
  ``Config.weight_sync_every`` = M (20) gradient steps (local: a seqlocked copy in
  shared memory, read by an actor before each batch when its version changed; Ray:
  one ``ray.put`` per publication, fetched by an actor with its next call). A batch
  is acted with weights at most M - 1 updates old when it starts, and then waits
  behind at most every actor's outstanding batches (D + 1 = 3 each: one being
  collected, two queued), so the lag in updates when it is stored is at most
  M + K (D + 1) actor_batch / train_every (39 at K = 1, 58 at K = 2 with the
  defaults). The bound holds when the learner is the bottleneck and every queue is
  full; with a faster learner the queues are empty and the lag is about half of
  M + K actor_batch / train_every. For scale: the target network is
  ``target_sync_every`` (1,000-2,000 env steps, 125-250 updates) old anyway. The
  measured mean lag is logged as ``charts/policy_lag_updates``.
* **ε** follows the single stream's schedule at the learner's global step; actors
  read it with the weights (local) or receive it with each call (Ray).
* **Seeding.** Episode k of actor i draws its episode seed, its ε draws and its
  random actions from ``SeedSequence(run seed, spawn_key=(i, k))``: the same run
  seed gives actor i the same sequence of episodes (lead trajectory, initial gap and
  speeds) and, with the same weights, the same actions (test
  ``test_actor_episodes_are_a_function_of_seed_and_index``). Which batch reaches the
  learner first is up to the OS and the network, so a K-stream run as a whole is not
  bit-reproducible.
* **Restarts.** A dead actor is restarted without stopping training: by Ray
  (``max_restarts``; ``max_task_retries=0`` so that the learner sees the failed call,
  logs it and resubmits knowing which batches were lost), or, without Ray, by the
  learner itself, which restarts the process up to ``max_restarts`` times. A new
  incarnation starts a new episode, numbered after the last episode the learner
  received from that actor, so it continues the actor's seed sequence. The learner
  logs ``charts/actor_restarts``; a permanently dead actor is dropped and training
  goes on with the rest (it stops with an error only when none is left).
* **Resume** (``--resume`` with ``--servers K``) restores the weights, target,
  optimizer, the K replay streams, the step and update counts and the per-actor
  episode counters. It is approximate: the actors start new episodes (the episodes
  open at the checkpoint stay in replay, unfinished), and the arrival order of
  batches differs from an uninterrupted run.
* **Processes.** Every actor owns its server (``--parent-pid``: it exits when its
  actor dies, even by ``kill -9``). Local actors run in their own process group (a
  terminal's Ctrl-C reaches the learner only, which then stops them in order), watch
  for the learner's death, and are stopped at exit with a shared flag, then SIGTERM,
  then SIGKILL. They share no lock with the learner (an actor killed holding one
  would block the learner forever). Ray actors are asked to close, then killed; a Ray instance that
  :func:`train_distributed` started is shut down.

Run folder: as :func:`agent_client.ddqn.train`, with the replay in one file per
stream, ``replay-<step>-<i>.npz``, named by ``latest.pt``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import multiprocessing as mp
import os
import queue
import random
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as wait_connections
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch.nn.utils import parameters_to_vector, vector_to_parameters

from agent_client.ddqn import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    N_ACTIONS,
    SESSION_TIMEOUT,
    Config,
    Progress,
    QNetwork,
    ReplayMemory,
    ScalarLog,
    _atomic_save,
    _config_dict,
    _load_weights,
    _read_checkpoint,
    check_resume_config,
    dqn_update,
    eval_episode,
    evaluate,
    init_from_policy,
    linear_schedule,
    log_evaluation,
    save_policy,
)
from agent_client.errors import ClientError, InputFileError

__all__ = [
    "StreamActor",
    "StreamReplay",
    "train_distributed",
    "episode_rng",
    "import_ray",
    "RayMissingError",
    "RAY_INSTALL_HINT",
    "MAX_RESTARTS",
]

RAY_INSTALL_HINT = "--ray needs Ray, an optional extra: pip install 'vacc[ray]' (or: pip install 'ray>=2.9')"
MAX_RESTARTS = 3  # restarts per actor before it is given up
STALL_TIMEOUT = 300.0  # [s] no batch from any actor for this long: stop with an error
RESTART_TIMEOUT = 120.0  # [s] an actor failing calls for this long is given up
STARTUP_TIMEOUT = 120.0  # [s] the learner waits this long for every actor's server at the start
RETRY_DELAY = 0.5  # [s] before a failed Ray call is resubmitted
STOP_TIMEOUT = 20.0  # [s] an actor asked to stop gets this long before SIGTERM


class RayMissingError(ImportError, ClientError):
    """``--ray`` was asked for and Ray is not installed."""


def import_ray() -> Any:
    """The ``ray`` module.

    Raises:
        RayMissingError: Ray is not installed; the message says how to install it.
    """
    # Ray's crash handler would print a C++ stack dump and abort on every SIGTERM,
    # before our finally blocks reap the actors. Set the variable to 0 to keep it.
    os.environ.setdefault("RAY_DISABLE_FAILURE_SIGNAL_HANDLER", "1")
    try:
        import ray
    except ImportError:
        raise RayMissingError(RAY_INSTALL_HINT) from None
    return ray


def episode_rng(seed: int, actor: int, episode: int) -> np.random.Generator:
    """The generator of episode ``episode`` of actor ``actor``: its seed, ε draws, random actions."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(actor, episode)))


def _flat_weights(q: QNetwork) -> np.ndarray:
    """The network's parameters as one float32 vector on the CPU (2.8 MB)."""
    return parameters_to_vector(q.parameters()).detach().cpu().numpy().astype(np.float32, copy=False)


# --------------------------------------------------------------------------- actor


class StreamActor:
    """One acting stream: a spawned simulator server, its env and a CPU copy of the policy.

    Used as is by a local actor process and wrapped by the Ray actor. It keeps its
    episode open across :meth:`collect` calls.

    Args:
        cfg: the run's settings.
        index: i, the actor's number (seeds its episodes).
        server_args: extra ``python -m sim_server`` arguments.
        episode_base: the episode number to start at (after a restart: one past the
            last episode the learner received from this actor).
    """

    _made = 0  # StreamActors made in this process (tells incarnations apart)

    def __init__(self, cfg: Config, index: int, server_args: tuple[str, ...] = (), episode_base: int = 0):
        from agent_client.env import VisionACCEnv  # spawns the server; import late

        torch.set_num_threads(1)  # one core per actor; its server takes the rest
        self.cfg, self.index = cfg, index
        StreamActor._made += 1
        self.token = f"{os.getpid()}.{StreamActor._made}"
        self.env = VisionACCEnv(
            scenario=cfg.scenario, trajectory="random", reward=cfg.reward, frame_stack=cfg.frame_stack,
            stack_stride=cfg.stack_stride, episode_seconds=cfg.episode_seconds, zoom=cfg.zoom,
            server_args=("--session-timeout", str(SESSION_TIMEOUT), *server_args),
        )  # fmt: skip
        self.q = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale).eval()
        self.version = -1
        self.episode = episode_base
        self._obs: dict[str, np.ndarray] | None = None
        self._rng: np.random.Generator | None = None

    def set_weights(self, flat: np.ndarray, version: int) -> None:
        """Load the learner's weights (a :func:`_flat_weights` vector) published at ``version`` updates."""
        vector_to_parameters(torch.tensor(flat, dtype=torch.float32), self.q.parameters())
        self.version = version

    def collect(self, n: int, epsilon: float) -> dict[str, Any]:
        """Play ``n`` transitions ε-greedily; returns them as one batch.

        Returns:
            ``frames`` ``[m, 105, 150]`` uint8 and ``speeds`` ``[m]`` [m/s] of the m
            records (one per transition, plus one per episode start); ``start``
            ``[m]``; ``actions``, ``rewards``, ``terminated``, ``truncated`` ``[m]`` of
            the transition into each non-start record; ``episode`` ``[m]`` the
            episode number of each record; ``actor``, ``token`` (this incarnation),
            ``pid``, ``version`` (the weights acted with), ``steps`` (= n),
            ``busy_s`` (seconds spent collecting).
        """
        t0 = time.perf_counter()
        frames, speeds, start, actions, rewards, terminated, truncated, episode = ([] for _ in range(8))

        def record(obs: dict[str, np.ndarray], is_start: bool, a: int = 0, r: float = 0.0, term: bool = False, trunc: bool = False) -> None:
            frames.append(obs["frames"][-1])  # only the newest frame: the learner rebuilds stacks
            speeds.append(obs["speeds"][-1])
            start.append(is_start)
            actions.append(a)
            rewards.append(r)
            terminated.append(term)
            truncated.append(trunc)
            episode.append(self.episode)

        for _ in range(n):
            if self._obs is None:
                self._rng = episode_rng(self.cfg.seed, self.index, self.episode)
                self._obs, _ = self.env.reset(options={"seed": int(self._rng.integers(2**31))})
                record(self._obs, True)
            assert self._rng is not None
            if self._rng.random() < epsilon:
                action = int(self._rng.integers(N_ACTIONS))
            else:
                with torch.inference_mode():
                    qv = self.q(torch.from_numpy(self._obs["frames"])[None], torch.from_numpy(self._obs["speeds"])[None])  # [1, A]
                action = int(qv.argmax(dim=1).item())
            next_obs, reward, term, trunc, _ = self.env.step(action)
            record(next_obs, False, action, reward, term, trunc)
            self._obs = next_obs
            if term or trunc:
                self._obs = None
                self.episode += 1
        return {
            "frames": np.stack(frames),
            "speeds": np.asarray(speeds, np.float32),
            "start": np.asarray(start, np.bool_),
            "actions": np.asarray(actions, np.uint8),
            "rewards": np.asarray(rewards, np.float32),
            "terminated": np.asarray(terminated, np.bool_),
            "truncated": np.asarray(truncated, np.bool_),
            "episode": np.asarray(episode, np.int64),
            "actor": self.index,
            "token": self.token,
            "pid": os.getpid(),
            "version": self.version,
            "steps": n,
            "busy_s": time.perf_counter() - t0,
        }

    def close(self) -> None:
        """Close the env, which reaps the server. Safe to call twice."""
        self.env.close()


class _RayStream:
    """The body of a Ray actor: builds its :class:`StreamActor` lazily, so that a
    failure to start a server comes back from :meth:`collect` as an error the learner
    logs, and the next call tries again."""

    def __init__(self, cfg: Config, index: int, server_args: tuple[str, ...]):
        self.cfg, self.index, self.server_args = cfg, index, server_args
        self.actor: StreamActor | None = None

    def start(self, episode_base: int) -> int:
        """Start the server and env now (else the first :meth:`collect` does); returns the pid."""
        try:
            if self.actor is None:
                self.actor = StreamActor(self.cfg, self.index, self.server_args, episode_base)
        except BaseException:
            self.close()
            raise
        return os.getpid()

    def collect(self, n: int, epsilon: float, weights: list[Any], version: int, episode_base: int) -> dict[str, Any]:
        import ray

        try:
            if self.actor is None:
                self.actor = StreamActor(self.cfg, self.index, self.server_args, episode_base)
            if version != self.actor.version:
                self.actor.set_weights(ray.get(weights[0]), version)  # weights boxed in a list: fetched only when new
            return self.actor.collect(n, epsilon)
        except BaseException:
            self.close()  # the next call starts a new incarnation
            raise

    def close(self) -> None:
        if self.actor is not None:
            self.actor.close()
            self.actor = None


# ------------------------------------------------------------------- local actors


class _Shared:
    """What the learner shares with its local actors: weights, ε and a stop flag.

    The weights are a seqlock (one writer, readers that retry): no lock is held by
    an actor, because an actor killed while holding a ``multiprocessing.Lock`` (or
    inside ``Event.is_set``) would block the learner forever.
    """

    def __init__(self, ctx: Any, n_params: int):
        self.data = ctx.RawArray("f", n_params)
        self.seq = ctx.RawValue("q", 0)  # odd while the learner writes
        self.version = ctx.RawValue("q", -1)
        self.epsilon = ctx.RawValue("d", 1.0)
        self.stop = ctx.RawValue("b", 0)

    def write(self, flat: np.ndarray, version: int) -> None:
        """(Learner) publish the weights of ``version`` updates."""
        self.seq.value += 1
        np.frombuffer(self.data, np.float32)[:] = flat
        self.version.value = version
        self.seq.value += 1

    def read(self) -> tuple[np.ndarray, int] | None:
        """(Actor) a consistent copy of the weights and their version; None if the
        learner kept writing through 100 tries (the actor keeps its old weights)."""
        for _ in range(100):
            seq = self.seq.value
            if seq % 2 == 0:
                flat, version = np.frombuffer(self.data, np.float32).copy(), self.version.value
                if self.seq.value == seq:
                    return flat, version
            time.sleep(0.001)
        return None


def _local_actor_main(
    cfg: Config, index: int, server_args: tuple[str, ...], episode_base: int, out: Connection, shared: _Shared, learner_pid: int
) -> None:
    """A local actor process: collect batches and send them until told to stop or orphaned."""
    os.setpgrp()  # a terminal's Ctrl-C goes to the learner, which stops us in order
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def _terminate(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _terminate)
    alive = lambda: not shared.stop.value and os.getppid() == learner_pid  # noqa: E731
    outbox: queue.Queue[dict[str, Any] | None] = queue.Queue(maxsize=1)

    def send() -> None:  # a thread, so that the next batch is collected while this one is sent
        with contextlib.suppress(OSError, EOFError):
            while (batch := outbox.get()) is not None:
                out.send(batch)  # blocks while the learner is behind: backpressure

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    actor = None
    try:
        actor = StreamActor(cfg, index, server_args, episode_base)
        outbox.put({"ready": os.getpid()})
        while alive():
            if shared.version.value != actor.version and (got := shared.read()) is not None:
                actor.set_weights(*got)
            batch = actor.collect(cfg.actor_batch, shared.epsilon.value)
            while alive():
                try:
                    outbox.put(batch, timeout=0.5)
                    break
                except queue.Full:
                    continue
    finally:
        if actor is not None:
            actor.close()
        with contextlib.suppress(queue.Full):
            outbox.put_nowait(None)  # ends the sender; if it is stuck in send, exit abandons it


def _ready(conns: list[Connection], timeout: float) -> list[Connection]:
    """The connections with a message (or EOF) within ``timeout`` [s]."""
    return cast("list[Connection]", wait_connections(conns, timeout))


@dataclass
class _Local:
    """One incarnation of a local actor: its process and the reading end of its pipe."""

    proc: Any
    conn: Connection


class _LocalPool:
    """K actor processes (spawn context), restarted by the learner when they die."""

    backend = "local"

    def __init__(self, cfg: Config, server_args: tuple[str, ...], max_restarts: int, n_params: int):
        self.cfg, self.server_args, self.max_restarts = cfg, server_args, max_restarts
        self.ctx = mp.get_context("spawn")
        self.shared = _Shared(self.ctx, n_params)
        self.actors: list[_Local | None] = [None] * cfg.servers
        self.restarts = [0] * cfg.servers

    def start(self, episode_bases: list[int], note: Callable[[str], None]) -> None:
        """Spawn the actors and wait (up to ``STARTUP_TIMEOUT``) until each has its server."""
        for i in range(self.cfg.servers):
            self._spawn(i, episode_bases[i])
        waiting = {a.conn: i for i, a in enumerate(self.actors) if a is not None}
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while waiting and time.monotonic() < deadline:
            for conn in _ready(list(waiting), min(1.0, max(0.0, deadline - time.monotonic()))):
                i = waiting.pop(conn)
                try:
                    conn.recv()
                except (EOFError, OSError):
                    self._died(i, episode_bases[i], note)  # its replacement is not waited for
        if waiting:
            note(f"actors {sorted(waiting.values())} not ready after {STARTUP_TIMEOUT:.0f} s; starting without waiting for them")

    def _spawn(self, i: int, episode_base: int) -> None:
        reader, writer = self.ctx.Pipe(duplex=False)
        args = (self.cfg, i, self.server_args, episode_base, writer, self.shared, os.getpid())
        proc = self.ctx.Process(target=_local_actor_main, args=args, name=f"vacc-actor-{i}", daemon=True)
        proc.start()
        writer.close()  # ours: so that the reader sees EOF when the actor dies, even mid-message
        self.actors[i] = _Local(proc, reader)

    def publish(self, flat: np.ndarray, version: int, epsilon: float) -> None:
        self.shared.write(flat, version)
        self.shared.epsilon.value = epsilon

    def set_epsilon(self, epsilon: float) -> None:
        self.shared.epsilon.value = epsilon

    def alive(self) -> int:
        return sum(a is not None for a in self.actors)

    def poll(self, timeout: float, episode_bases: list[int], note: Callable[[str], None]) -> list[tuple[int, dict[str, Any]]]:
        """Batches that have arrived within ``timeout`` [s]; restarts actors that died."""
        conns = {a.conn: i for i, a in enumerate(self.actors) if a is not None}
        got = []
        for conn in _ready(list(conns), timeout):
            i = conns[conn]
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                self._died(i, episode_bases[i], note)
                continue
            if "ready" not in msg:  # a restarted actor says it is ready first
                got.append((i, msg))
        return got

    def _died(self, i: int, episode_base: int, note: Callable[[str], None]) -> None:
        a = self.actors[i]
        assert a is not None
        a.conn.close()
        a.proc.join(timeout=5)
        code = a.proc.exitcode
        if self.restarts[i] >= self.max_restarts:
            self.actors[i] = None
            note(f"actor {i} died (exit code {code}) after {self.restarts[i]} restarts: given up")
            return
        self.restarts[i] += 1
        note(f"actor {i} died (exit code {code}); restarting it ({self.restarts[i]}/{self.max_restarts}) at episode {episode_base}")
        self._spawn(i, episode_base)

    def close(self) -> None:
        self.shared.stop.value = 1
        deadline = time.monotonic() + STOP_TIMEOUT
        for a in self.actors:
            if a is not None:
                a.proc.join(timeout=max(0.1, deadline - time.monotonic()))
        for a in self.actors:
            if a is None:
                continue
            if a.proc.is_alive():
                a.proc.terminate()  # SIGTERM: its finally block reaps its server
                a.proc.join(timeout=10)
            if a.proc.is_alive():
                a.proc.kill()  # its server exits by itself (--parent-pid)
                a.proc.join(timeout=5)
            a.conn.close()
        self.actors = [None] * self.cfg.servers


# --------------------------------------------------------------------- Ray actors


class _RayPool:
    """K Ray actors; two ``collect`` calls in flight per actor."""

    backend = "ray"
    depth = 2

    def __init__(self, cfg: Config, server_args: tuple[str, ...], max_restarts: int, address: str | None, actor_cpus: float):
        ray = self.ray = import_ray()
        self.cfg = cfg
        self.owns_ray = not ray.is_initialized()
        if self.owns_ray:
            # A local instance listens on loopback only; a cluster address is the user's call.
            local = address is None and not os.environ.get("RAY_ADDRESS")
            ray.init(address=address, include_dashboard=False, **({"_node_ip_address": "127.0.0.1"} if local else {}))
        try:
            cpus = ray.cluster_resources().get("CPU", 0.0)
            need = cfg.servers * actor_cpus
            if need > cpus:
                message = f"{cfg.servers} actors x {actor_cpus:g} CPU need {need:g} CPUs; the Ray cluster has {cpus:g}"
                if address is None:  # a fixed local instance: the actors would wait forever
                    raise ClientError(f"{message}: lower --actor-cpus or --servers, or connect to a bigger cluster (--ray-address)")
                print(f"warning: {message} (waiting for the cluster to scale up)", file=sys.stderr)
            remote = ray.remote(num_cpus=actor_cpus, max_restarts=max_restarts, max_task_retries=0, scheduling_strategy="SPREAD")(_RayStream)
            self.handles = [remote.remote(cfg, i, server_args) for i in range(cfg.servers)]
        except BaseException:
            if self.owns_ray:
                ray.shutdown()
            raise
        self.dead = [False] * cfg.servers
        self.failing_since: list[float | None] = [None] * cfg.servers
        self.restarts = [0] * cfg.servers  # counted by the learner from new incarnations
        self.inflight: dict[Any, int] = {}
        self.retries: dict[int, tuple[float, int]] = {}  # actor -> (when, calls) to resubmit
        self.weights: Any = None
        self.version = -1
        self.epsilon = 1.0

    def start(self, episode_bases: list[int], note: Callable[[str], None]) -> None:
        """Start every actor's server, wait (up to ``STARTUP_TIMEOUT``) for them, then the calls."""
        ray = self.ray
        starting = {h.start.remote(episode_bases[i]): i for i, h in enumerate(self.handles)}
        ready, rest = ray.wait(list(starting), num_returns=len(starting), timeout=STARTUP_TIMEOUT)
        for ref in ready:
            try:
                ray.get(ref)
            except (ray.exceptions.RayActorError, ray.exceptions.RayTaskError) as exc:
                note(f"actor {starting[ref]} failed to start ({type(exc).__name__}: {_first_line(exc)}); its calls will retry")
        if rest:
            note(f"actors {sorted(starting[r] for r in rest)} not ready after {STARTUP_TIMEOUT:.0f} s; starting without waiting for them")
        for i in range(self.cfg.servers):
            for _ in range(self.depth):
                self._submit(i, episode_bases[i])

    def _submit(self, i: int, episode_base: int) -> None:
        ref = self.handles[i].collect.remote(self.cfg.actor_batch, self.epsilon, [self.weights], self.version, episode_base)
        self.inflight[ref] = i

    def publish(self, flat: np.ndarray, version: int, epsilon: float) -> None:
        self.weights, self.version, self.epsilon = self.ray.put(flat), version, epsilon

    def set_epsilon(self, epsilon: float) -> None:
        self.epsilon = epsilon

    def alive(self) -> int:
        return self.dead.count(False)

    def poll(self, timeout: float, episode_bases: list[int], note: Callable[[str], None]) -> list[tuple[int, dict[str, Any]]]:
        """Batches that have arrived within ``timeout`` [s]; each is replaced by a new call.

        A failed call is resubmitted after ``RETRY_DELAY`` (Ray may still be restarting
        the actor), with the episode number the learner has reached for it."""
        ray = self.ray
        now = time.monotonic()
        for i, (when, calls) in list(self.retries.items()):
            if when <= now:
                del self.retries[i]
                for _ in range(calls):
                    self._submit(i, episode_bases[i])
        if not self.inflight:
            time.sleep(min([timeout, *(when - now for when, _ in self.retries.values())]) if self.retries else timeout)
            return []
        ready, rest = ray.wait(list(self.inflight), num_returns=1, timeout=timeout)
        if ready and rest:
            ready += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
        got = []
        for ref in ready:
            i = self.inflight.pop(ref)
            try:
                got.append((i, ray.get(ref)))
                self.failing_since[i] = None
            except ray.exceptions.ActorDiedError as exc:  # Ray has no restart left for it
                if not self.dead[i]:
                    self.dead[i] = True
                    note(f"actor {i} is dead and Ray will not restart it: {_first_line(exc)}")
                    self.retries.pop(i, None)
                continue
            except (ray.exceptions.RayActorError, ray.exceptions.RayTaskError) as exc:
                # ActorUnavailableError: Ray is restarting it. RayTaskError: collect raised
                # (e.g. its server failed); the actor starts a new incarnation at its next call.
                now = time.monotonic()
                if self.failing_since[i] is None or isinstance(exc, ray.exceptions.RayTaskError):
                    note(f"actor {i}: call failed ({type(exc).__name__}: {_first_line(exc)}); resubmitting")
                since = self.failing_since[i] = self.failing_since[i] or now
                if now - since > RESTART_TIMEOUT:
                    self.dead[i] = True
                    self.retries.pop(i, None)
                    note(f"actor {i} has failed every call for {RESTART_TIMEOUT:.0f} s: given up")
                elif not self.dead[i]:
                    when, calls = self.retries.get(i, (now + RETRY_DELAY, 0))
                    self.retries[i] = (when, calls + 1)
                continue
            self._submit(i, episode_bases[i])
        return got

    def close(self) -> None:
        ray = self.ray
        try:
            closing = [h.close.remote() for i, h in enumerate(self.handles) if not self.dead[i]]
            with contextlib.suppress(Exception):
                ray.wait(closing, num_returns=len(closing), timeout=STOP_TIMEOUT)  # reaps their servers
            for h in self.handles:
                with contextlib.suppress(Exception):
                    ray.kill(h, no_restart=True)  # a server left behind exits by itself (--parent-pid)
        finally:
            if self.owns_ray:
                ray.shutdown()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else type(exc).__name__


# -------------------------------------------------------------------------- replay


class StreamReplay:
    """K replay streams, one :class:`ReplayMemory` per actor, sampled as one memory.

    Args:
        cfg: ``buffer_size`` is split evenly over ``servers`` streams.
    """

    def __init__(self, cfg: Config):
        k = cfg.servers
        sizes = [cfg.buffer_size // k + (i < cfg.buffer_size % k) for i in range(k)]
        self.streams = [ReplayMemory(c, cfg.frame_stack, cfg.stack_stride) for c in sizes]

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

    def sample(self, batch_size: int, rng: np.random.Generator, n_step: int = 1, gamma: float = 0.99) -> dict[str, np.ndarray]:
        """A batch uniform over every stored slot of every stream (see :meth:`ReplayMemory.sample`)."""
        sizes = np.array([len(m) if m.transitions > 0 else 0 for m in self.streams], np.float64)
        if sizes.sum() == 0:
            raise RuntimeError("replay memory holds no complete transition")
        counts = rng.multinomial(batch_size, sizes / sizes.sum())
        parts = [m.sample(int(c), rng, n_step, gamma) for m, c in zip(self.streams, counts, strict=True) if c > 0]
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def save(self, run_dir: Path, step: int) -> list[str]:
        """Write every stream as ``replay-<step>-<i>.npz``; returns the names."""
        names = [f"replay-{step}-{i}.npz" for i in range(len(self.streams))]
        for m, name in zip(self.streams, names, strict=True):
            m.save(run_dir / name, step)
        return names

    def load(self, run_dir: Path, names: list[str], step: int) -> None:
        """Restore the streams written by :meth:`save` at ``step``.

        Raises:
            InputFileError: a file missing, unreadable, of another layout or another step.
        """
        if len(names) != len(self.streams):
            raise InputFileError(f"{run_dir}: checkpoint names {len(names)} replay streams, the run has {len(self.streams)}")
        for m, name in zip(self.streams, names, strict=True):
            saved = m.load(run_dir / name)
            if saved != step:
                raise InputFileError(f"{run_dir / name}: saved at step {saved}, but latest.pt is at step {step}")


# ------------------------------------------------------------------------ training


@dataclass
class _DState:
    """What a resumed K-stream run needs besides the weights and the replay streams."""

    global_step: int = 0
    updates: int = 0
    episodes: int = 0
    best_score: float = math.inf
    recent_returns: list[float] = field(default_factory=list)
    episodes_by_actor: list[int] = field(default_factory=list)  # next episode number of each actor
    transitions_by_actor: list[int] = field(default_factory=list)
    restarts_by_actor: list[int] = field(default_factory=list)


def _updates_owed(step: int, cfg: Config) -> int:
    """Gradient steps the single-stream loop would have taken by env step ``step``."""
    return max(0, step // cfg.train_every - cfg.learning_starts // cfg.train_every)


def train_distributed(
    cfg: Config,
    run_dir: str | Path,
    *,
    resume: bool = False,
    progress: bool = True,
    use_ray: bool = False,
    ray_address: str | None = None,
    actor_cpus: float = 1.0,
    max_restarts: int = MAX_RESTARTS,
    server_args: tuple[str, ...] = (),
    on_batch: Callable[[int, int, dict[str, Any]], None] | None = None,
    on_eval: Callable[[int, list[dict[str, Any]]], None] | None = None,
) -> dict[str, Any]:
    """Train a DDQN policy with ``cfg.servers`` acting streams feeding this learner.

    Args:
        cfg: the settings; ``cfg.servers`` is K.
        run_dir: ``runs/<name>``.
        resume: continue from ``run_dir/latest.pt`` and the replay streams it names
            (approximately: see the module docstring).
        progress: show the progress line on stderr.
        use_ray: run the actors as Ray actors (else local processes).
        ray_address: ``ray.init`` address (None: a local Ray instance, or ``RAY_ADDRESS``;
            "auto" or HOST:PORT: an existing cluster). Ignored if Ray is initialised.
        actor_cpus: CPUs Ray reserves per actor.
        max_restarts: restarts per actor before it is given up.
        server_args: extra ``python -m sim_server`` arguments for the actors' servers.
        on_batch: called with (step, actor, batch) after each batch is stored.
        on_eval: called with (step, results) after each evaluation.

    Returns:
        Summary: steps, updates, episodes, best score, last evaluation, wall time [s],
        env_steps_per_s (from the first batch on), transitions/restarts per actor,
        the actors' process ids.

    Raises:
        InputFileError: ``resume`` with a missing or bad checkpoint or replay file.
        RayMissingError: ``use_ray`` without Ray installed.
        ClientError: every actor died, or none delivered for ``STALL_TIMEOUT``.
    """
    from agent_client.env import VisionACCEnv  # the env spawns servers; import late

    if use_ray:
        import_ray()  # fail before any work if it is missing
    K = cfg.servers
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    latest, best_path = run_dir / "latest.pt", run_dir / "best.pt"
    eval_server_args = ("--session-timeout", str(SESSION_TIMEOUT), *server_args)

    # --- seeding: the one block (actors seed their episodes from (cfg.seed, i, k)). --
    random.seed(cfg.seed)
    np_rng = np.random.default_rng(cfg.seed)  # replay sampling
    torch.manual_seed(cfg.seed)
    torch.backends.cudnn.deterministic = True
    torch.set_num_threads(cfg.torch_threads)
    device = torch.device("cuda" if cfg.cuda and torch.cuda.is_available() else "cpu")

    q = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale).to(device)
    target = QNetwork(cfg.frame_stack, N_ACTIONS, cfg.speed_scale).to(device)
    target.load_state_dict(q.state_dict())
    optimizer = torch.optim.Adam(q.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
    replay = StreamReplay(cfg)
    state = _DState(episodes_by_actor=[0] * K, transitions_by_actor=[0] * K, restarts_by_actor=[0] * K)

    if not resume:
        init_from_policy(q, target, cfg)
    if resume:
        ckpt = _read_checkpoint(latest)
        if ckpt.get("kind") != "training" or ckpt.get("trainer") != "distributed":
            raise InputFileError(f"{latest}: not a checkpoint of a multi-server run (resume it without --servers/--ray)")
        check_resume_config(ckpt, cfg, latest)
        _load_weights(q, ckpt["model"], latest)
        _load_weights(target, ckpt["target"], latest, "target")
        try:
            optimizer.load_state_dict(ckpt["optimizer"])
            state = _DState(**ckpt["state"])
            np_rng.bit_generator.state = ckpt["rng"]["numpy"]
            names = list(ckpt["replay"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise InputFileError(f"{latest}: incomplete training state ({type(exc).__name__}: {exc})") from None
        replay.load(run_dir, names, state.global_step)
    (run_dir / "config.json").write_text(json.dumps(_config_dict(cfg), indent=2) + "\n")

    log = ScalarLog(run_dir, resume_step=state.global_step if resume else None)
    bar = Progress(cfg.total_steps, enabled=progress)
    recent = deque(state.recent_returns, maxlen=20)
    eval_env: VisionACCEnv | None = None
    last_eval: list[dict[str, Any]] = []
    t_start, steps_at_start = time.perf_counter(), state.global_step
    next_checkpoint = state.global_step + cfg.checkpoint_every
    next_eval = (state.global_step // cfg.eval_every + 1) * cfg.eval_every if cfg.eval_every > 0 else math.inf
    next_log = (state.global_step // cfg.log_every + 1) * cfg.log_every
    last_eval_step = -1
    synced_block = (cfg.learning_starts // cfg.train_every + state.updates) * cfg.train_every // cfg.target_sync_every
    ep_return, ep_len = [0.0] * K, [0] * K
    tokens: list[str | None] = [None] * K
    pids: set[int] = set()
    lags: list[int] = []
    first_batch: tuple[float, int] | None = None  # (time, step) when data first arrived
    restarts_at_start = list(state.restarts_by_actor)

    def note(message: str) -> None:
        sys.stderr.write(("\n" if bar.enabled and bar.tty else "") + f"vacc train: {message}\n")
        sys.stderr.flush()

    def epsilon() -> float:
        return linear_schedule(cfg.start_e, cfg.end_e, cfg.exploration_steps, state.global_step)

    def run_eval() -> None:
        nonlocal eval_env, last_eval
        if eval_env is None:
            eval_env = VisionACCEnv(
                scenario=cfg.scenario, trajectory=eval_episode(cfg.eval_trajectories[0])[0], reward=cfg.reward,
                frame_stack=cfg.frame_stack, stack_stride=cfg.stack_stride,
                episode_seconds=cfg.eval_seconds, server_args=eval_server_args, zoom=cfg.zoom,
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

    def checkpoint() -> None:
        state.recent_returns = list(recent)
        # As ddqn.train: the replay under new names first, then latest.pt naming them,
        # then the old files go. A kill -9 anywhere leaves a resumable set.
        names = replay.save(run_dir, state.global_step)
        _atomic_save(
            {
                "format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "kind": "training", "trainer": "distributed",
                "replay": names, "config": _config_dict(cfg), "model": q.state_dict(), "target": target.state_dict(),
                "optimizer": optimizer.state_dict(), "state": dataclasses.asdict(state),
                "rng": {"numpy": np_rng.bit_generator.state, "torch": torch.get_rng_state()},
            },
            latest,
        )  # fmt: skip
        for old in run_dir.glob("replay-*.npz"):
            if old.name not in names:
                old.unlink()
        log.flush()

    def ingest(i: int, batch: dict[str, Any]) -> None:
        """Store actor i's batch, up to the step budget, and log its finished episodes."""
        nonlocal first_batch
        if first_batch is None:
            first_batch = (time.perf_counter(), state.global_step)
        pids.add(int(batch["pid"]))
        if batch["token"] != tokens[i]:
            if tokens[i] is not None:
                state.restarts_by_actor[i] += 1
                note(f"actor {i} restarted (incarnation {batch['token']}); {sum(state.restarts_by_actor)} restarts so far")
                log.add("charts/actor_restarts", sum(state.restarts_by_actor), state.global_step)
            tokens[i] = batch["token"]
            assert batch["start"][0], "a new incarnation begins with an episode start"
        lags.append(state.updates - int(batch["version"]))
        for j in range(len(batch["start"])):
            if state.global_step >= cfg.total_steps:
                break
            frame, speed = batch["frames"][j], float(batch["speeds"][j])
            if batch["start"][j]:
                replay.start(i, frame, speed)
                ep_return[i], ep_len[i] = 0.0, 0
                state.episodes_by_actor[i] = int(batch["episode"][j]) + 1
                continue
            term, trunc, reward = bool(batch["terminated"][j]), bool(batch["truncated"][j]), float(batch["rewards"][j])
            replay.add(i, int(batch["actions"][j]), reward, term, trunc, frame, speed)
            state.global_step += 1
            state.transitions_by_actor[i] += 1
            ep_return[i] += reward
            ep_len[i] += 1
            if term or trunc:
                state.episodes += 1
                recent.append(ep_return[i])
                log.add("charts/episodic_return", ep_return[i], state.global_step)
                log.add("charts/episodic_length", ep_len[i], state.global_step)
                log.add("charts/mean_reward", ep_return[i] / max(ep_len[i], 1), state.global_step)
                log.add("charts/epsilon", epsilon(), state.global_step)

    def log_actors(sps: float) -> None:
        for i in range(K):
            log.add(f"charts/transitions/actor-{i}", state.transitions_by_actor[i], state.global_step)
        log.add("charts/actor_restarts", sum(state.restarts_by_actor), state.global_step)
        log.add("charts/actors_alive", pool.alive() if pool is not None else 0, state.global_step)
        log.add("charts/SPS", sps, state.global_step)
        log.add("charts/updates", state.updates, state.global_step)
        if lags:
            log.add("charts/policy_lag_updates", float(np.mean(lags)), state.global_step)
            lags.clear()

    pool: _LocalPool | _RayPool | None = None
    sps = 0.0
    try:
        n_params = sum(p.numel() for p in q.parameters())
        pool = (
            _RayPool(cfg, server_args, max_restarts, ray_address, actor_cpus) if use_ray else _LocalPool(cfg, server_args, max_restarts, n_params)
        )
        pool.publish(_flat_weights(q), state.updates, epsilon())
        pool.start(list(state.episodes_by_actor), note)
        last_data = time.monotonic()
        last_checkpoint_step = state.global_step
        while True:
            # 1. the gradient steps owed by the data received (the single stream's ratio)
            while state.updates < _updates_owed(state.global_step, cfg):
                b = replay.sample(cfg.batch_size, np_rng, cfg.n_step, cfg.gamma)
                loss, q_taken = dqn_update(q, target, optimizer, b, cfg, device)
                state.updates += 1
                step_u = (cfg.learning_starts // cfg.train_every + state.updates) * cfg.train_every  # its single-stream step
                if step_u % cfg.log_every < cfg.train_every:
                    log.add("losses/td_loss", loss.item(), state.global_step)
                    log.add("losses/q_values", q_taken.mean().item(), state.global_step)
                if step_u // cfg.target_sync_every > synced_block:
                    target.load_state_dict(q.state_dict())
                    synced_block = step_u // cfg.target_sync_every
                if state.updates % cfg.weight_sync_every == 0:
                    pool.publish(_flat_weights(q), state.updates, epsilon())
            # 2. evaluation and checkpoints on their step grids, and at the end
            finished = state.global_step >= cfg.total_steps
            if state.global_step >= next_log or finished:
                log_actors(sps)
                next_log = (state.global_step // cfg.log_every + 1) * cfg.log_every
            if cfg.eval_trajectories and (state.global_step >= next_eval or (finished and last_eval_step != state.global_step)):
                run_eval()
                last_eval_step = state.global_step
                while next_eval <= state.global_step:
                    next_eval += cfg.eval_every
            if state.global_step >= next_checkpoint or (finished and last_checkpoint_step != state.global_step):
                checkpoint()
                last_checkpoint_step = state.global_step
                next_checkpoint = state.global_step + cfg.checkpoint_every
            if finished:
                break
            # 3. the next batches
            pool.set_epsilon(epsilon())
            got = pool.poll(0.5, state.episodes_by_actor, note)
            if pool.alive() == 0:
                raise ClientError(f"every actor died (restarts: {state.restarts_by_actor}); see the messages above")
            if not got:
                if time.monotonic() - last_data > STALL_TIMEOUT:
                    raise ClientError(f"no transitions from any of the {K} actors for {STALL_TIMEOUT:.0f} s")
                continue
            last_data = time.monotonic()
            for i, batch in got:
                ingest(i, batch)
                if on_batch is not None:
                    on_batch(state.global_step, i, batch)
            sps = (state.global_step - steps_at_start) / max(time.perf_counter() - t_start, 1e-9)
            bar.update(state.global_step, sps, epsilon(), float(np.mean(recent)) if recent else float("nan"),
                       extra=f"actors {pool.alive()}/{K}  restarts {sum(state.restarts_by_actor)}")  # fmt: skip
        t_end = time.perf_counter()
        bar.update(state.global_step, sps, epsilon(), float(np.mean(recent)) if recent else float("nan"), force=True,
                   extra=f"actors {pool.alive()}/{K}  restarts {sum(state.restarts_by_actor)}")  # fmt: skip
    finally:
        bar.close()
        try:
            if pool is not None:
                pool.close()
        finally:
            log.close()
            if eval_env is not None:
                eval_env.close()
    t0, s0 = first_batch if first_batch is not None else (t_end, state.global_step)
    return {
        "steps": state.global_step,
        "updates": state.updates,
        "episodes": state.episodes,
        "best_score": state.best_score,
        "last_eval": last_eval,
        "wall_s": t_end - t_start,
        "env_steps_per_s": (state.global_step - s0) / max(t_end - t0, 1e-9),
        "servers": K,
        "backend": "ray" if use_ray else "local",
        "transitions_by_actor": list(state.transitions_by_actor),
        "restarts_by_actor": [r - r0 for r, r0 in zip(state.restarts_by_actor, restarts_at_start, strict=True)],
        "actor_pids": sorted(pids),
        "replay_bytes_per_transition": replay.nbytes / replay.capacity,
    }

