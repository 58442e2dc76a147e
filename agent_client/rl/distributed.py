"""Many simulator servers, one learner: Double DQN fed by K acting streams (issue #10).

``vacc train --servers K`` runs the K actors as local processes; ``vacc train --ray
--servers K`` runs them as Ray actors, on this machine or across a cluster. Both use
the same :class:`StreamActor` and the same learner loop, :func:`train_distributed`.
``--servers 1`` without ``--ray`` stays on :func:`agent_client.rl.train.train`, the
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
  batches differs from an uninterrupted run. So a checkpoint may be taken between
  any two batches, and the first Ctrl-C (:data:`~agent_client.rl.learner.STOP`)
  takes one before the next batch is stored.
* **Processes.** Every actor owns its server (``--parent-pid``: it exits when its
  actor dies, even by ``kill -9``). Local actors start with SIGINT ignored and run in
  their own process group (a terminal's Ctrl-C reaches the learner only, which saves
  and then stops them in order), watch
  for the learner's death, and are stopped at exit with a shared flag, then SIGTERM,
  then SIGKILL. They share no lock with the learner (an actor killed holding one
  would block the learner forever). Ray actors are asked to close, then killed; a Ray instance that
  :func:`train_distributed` started is shut down.

Run folder: as :func:`agent_client.rl.train.train`, with the replay in one file per
stream, ``replay-<step>-<i>.npz``, named by ``latest.pt``.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import queue
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as wait_connections
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch.nn.utils import vector_to_parameters

from agent_client.errors import ClientError
from agent_client.rl.config import Config, single_stream_only
from agent_client.rl.learner import SESSION_TIMEOUT, STOP, Learner
from agent_client.rl.network import N_ACTIONS, QNetwork, greedy_action, linear_schedule
from agent_client.rl.replay import StreamReplay
from agent_client.rl.scalars import Progress
from agent_client.rl.stop import reinstall_stop_handler

__all__ = [
    "StreamActor",
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
            stack_stride=cfg.stack_stride, episode_seconds=cfg.episode_seconds, zoom=cfg.zoom, set_speed=cfg.set_speed,
            server_args=("--session-timeout", str(SESSION_TIMEOUT), *server_args), eco_weights=cfg.eco_weights, crash_reward=cfg.crash_reward,
        )  # fmt: skip
        self.q = QNetwork.of(cfg).eval()
        self.version = -1
        self.episode = episode_base
        self._obs: dict[str, np.ndarray] | None = None
        self._rng: np.random.Generator | None = None

    def set_weights(self, flat: np.ndarray, version: int) -> None:
        """Load the learner's weights (a :meth:`Learner.flat_weights` vector) published at ``version`` updates."""
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
                action = greedy_action(self.q, self._obs["frames"], self._obs["speeds"])
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
        # An ignored signal stays ignored across exec, and Python keeps it so: a terminal's
        # Ctrl-C during the seconds the actor imports (before its setpgrp) does not kill it.
        # Blocked here meanwhile, one that arrives while we start it stays pending instead of
        # being dropped, and reaches our handler once both are restored (handler first).
        main = threading.current_thread() is threading.main_thread()  # signal.signal works only there
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            proc.start()
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
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
            reinstall_stop_handler()  # ray.init takes SIGTERM for an exit at once: a kill still checkpoints
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


# ------------------------------------------------------------------------ training


def _updates_owed(step: int, cfg: Config) -> int:
    """Gradient steps the single-stream loop would have taken by env step ``step``."""
    return max(0, step // cfg.train_every - cfg.learning_starts // cfg.train_every)


class _StreamsLoop:
    """The K-stream loop's state: the learner, the replay streams, the actors' bookkeeping."""

    def __init__(self, cfg: Config, learner: Learner, replay: StreamReplay, progress: bool,
                 on_batch: Callable[[int, int, dict[str, Any]], None] | None):  # fmt: skip
        K = cfg.servers
        self.cfg, self.learner, self.replay, self.on_batch = cfg, learner, replay, on_batch
        saved = learner.saved
        self.step = int(saved.get("global_step", 0))
        self.episodes = int(saved.get("episodes", 0))
        self.recent = deque(saved.get("recent_returns", []), maxlen=20)
        self.episodes_by_actor = list(saved.get("episodes_by_actor", [0] * K))
        self.transitions_by_actor = list(saved.get("transitions_by_actor", [0] * K))
        self.restarts_by_actor = list(saved.get("restarts_by_actor", [0] * K))
        self.restarts_at_start = list(self.restarts_by_actor)
        self.bar = Progress(cfg.total_steps, enabled=progress, initial=self.step)
        self.ep_return, self.ep_len = [0.0] * K, [0] * K
        self.tokens: list[str | None] = [None] * K
        self.pids: set[int] = set()
        self.lags: list[int] = []
        self.first_batch: tuple[float, int] | None = None  # (time, step) when data first arrived
        self.synced_block = (cfg.learning_starts // cfg.train_every + learner.updates) * cfg.train_every // cfg.target_sync_every
        self.t_start, self.steps_at_start = time.perf_counter(), self.step
        self.sps = 0.0

    def state(self) -> dict[str, Any]:
        """The loop state a checkpoint keeps."""
        return {"global_step": self.step, "episodes": self.episodes, "recent_returns": list(self.recent),
                "episodes_by_actor": list(self.episodes_by_actor), "transitions_by_actor": list(self.transitions_by_actor),
                "restarts_by_actor": list(self.restarts_by_actor)}  # fmt: skip

    def note(self, message: str) -> None:
        self.bar.write(f"vacc train: {message}")

    def epsilon(self) -> float:
        return linear_schedule(self.cfg.start_e, self.cfg.end_e, self.cfg.exploration_steps, self.step)

    def learn(self, pool: _LocalPool | _RayPool) -> None:
        """The gradient steps owed by the data received (the single stream's ratio)."""
        cfg, learner = self.cfg, self.learner
        while learner.updates < _updates_owed(self.step, cfg):
            step_u = (cfg.learning_starts // cfg.train_every + learner.updates + 1) * cfg.train_every  # its single-stream step
            log = step_u % cfg.log_every < cfg.train_every
            losses = learner.update(self.replay.sample(cfg.batch_size, learner.rng, cfg.n_step, cfg.gamma), self.step if log else None)
            if losses is not None:
                learner.log.add("losses/td_loss", losses[0], self.step)
                learner.log.add("losses/q_values", losses[1], self.step)
            if step_u // cfg.target_sync_every > self.synced_block:
                learner.sync_target()
                self.synced_block = step_u // cfg.target_sync_every
            if learner.updates % cfg.weight_sync_every == 0:
                pool.publish(learner.flat_weights(), learner.updates, self.epsilon())

    def _first_start(self, i: int, batch: dict[str, Any]) -> int:
        """Index of the first record to store: 0, or past a new incarnation's leading
        records that continue an episode this learner never saw begin."""
        if batch["token"] == self.tokens[i]:
            return 0
        if self.tokens[i] is not None:
            self.restarts_by_actor[i] += 1
            self.note(f"actor {i} restarted (incarnation {batch['token']}); {sum(self.restarts_by_actor)} restarts so far")
            self.learner.log.add("charts/actor_restarts", sum(self.restarts_by_actor), self.step)
        self.tokens[i] = batch["token"]
        starts = np.flatnonzero(batch["start"])
        first = int(starts[0]) if len(starts) else len(batch["start"])
        if first > 0:  # e.g. a batch of the new incarnation that overtook its first one
            self.note(f"actor {i}: dropped {first} records that continue an episode whose start never arrived")
        return first

    def ingest(self, i: int, batch: dict[str, Any]) -> None:
        """Store actor i's batch, up to the step budget, and log its finished episodes."""
        if self.first_batch is None:
            self.first_batch = (time.perf_counter(), self.step)
        self.pids.add(int(batch["pid"]))
        self.lags.append(self.learner.updates - int(batch["version"]))
        log = self.learner.log
        for j in range(self._first_start(i, batch), len(batch["start"])):
            if self.step >= self.cfg.total_steps:
                break
            frame, speed = batch["frames"][j], float(batch["speeds"][j])
            if batch["start"][j]:
                self.replay.start(i, frame, speed)
                self.ep_return[i], self.ep_len[i] = 0.0, 0
                self.episodes_by_actor[i] = int(batch["episode"][j]) + 1
                continue
            term, trunc, reward = bool(batch["terminated"][j]), bool(batch["truncated"][j]), float(batch["rewards"][j])
            self.replay.add(i, int(batch["actions"][j]), reward, term, trunc, frame, speed)
            self.step += 1
            self.transitions_by_actor[i] += 1
            self.ep_return[i] += reward
            self.ep_len[i] += 1
            if term or trunc:
                self.episodes += 1
                self.recent.append(self.ep_return[i])
                for name, value in (("episodic_return", self.ep_return[i]), ("episodic_length", self.ep_len[i]),
                                    ("mean_reward", self.ep_return[i] / max(self.ep_len[i], 1)), ("epsilon", self.epsilon())):  # fmt: skip
                    log.add(f"charts/{name}", value, self.step)

    def log_actors(self, pool: _LocalPool | _RayPool) -> None:
        log, step = self.learner.log, self.step
        for i, n in enumerate(self.transitions_by_actor):
            log.add(f"charts/transitions/actor-{i}", n, step)
        for name, value in (("actor_restarts", sum(self.restarts_by_actor)), ("actors_alive", pool.alive()),
                            ("SPS", self.sps), ("updates", self.learner.updates)):  # fmt: skip
            log.add(f"charts/{name}", value, step)
        if self.lags:
            log.add("charts/policy_lag_updates", float(np.mean(self.lags)), step)
            self.lags.clear()

    def show(self, pool: _LocalPool | _RayPool, force: bool = False) -> None:
        recent = float(np.mean(self.recent)) if self.recent else float("nan")
        extra = f"actors {pool.alive()}/{self.cfg.servers}  restarts {sum(self.restarts_by_actor)}"
        self.bar.update(self.step, self.epsilon(), recent, force=force, extra=extra)


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
    """Train a DDQN policy with ``cfg.servers`` acting streams feeding one :class:`Learner`.

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
        the actors' process ids, whether :data:`STOP` ended it.

    Raises:
        InputFileError: ``resume`` with a missing or bad checkpoint or replay file.
        RayMissingError: ``use_ray`` without Ray installed.
        ClientError: every actor died, or none delivered for ``STALL_TIMEOUT``.
        ValueError: an option only the single-stream trainer honours (:func:`~agent_client.rl.config.single_stream_only`).
    """
    if (needs := single_stream_only(cfg)) is not None:
        raise ValueError(needs[1])
    if use_ray:
        import_ray()  # fail before any work if it is missing
    replay = StreamReplay(cfg.buffer_size, cfg.servers, cfg.frame_stack, cfg.stack_stride)

    def load_replay(learner: Learner) -> None:
        replay.load(learner.run_dir, learner.replay_names, int(learner.saved.get("global_step", 0)))

    learner = Learner(cfg, run_dir, resume=resume, trainer="streams", server_args=server_args, on_eval=on_eval, load_replay=load_replay)
    pool: _LocalPool | _RayPool | None = None
    try:
        loop = _StreamsLoop(cfg, learner, replay, progress, on_batch)
        n_params = sum(p.numel() for p in learner.q.parameters())
        pool = _RayPool(cfg, server_args, max_restarts, ray_address, actor_cpus) if use_ray else _LocalPool(cfg, server_args, max_restarts, n_params)
        t_end = _run_streams(loop, pool)
    finally:
        try:
            if pool is not None:
                pool.close()
        finally:
            learner.close()
    return _summary(loop, learner, replay, cfg, t_end, use_ray)


def _run_streams(loop: _StreamsLoop, pool: _LocalPool | _RayPool) -> float:
    """Learn, evaluate, checkpoint and take the actors' batches until the step budget; returns the end time."""
    cfg, learner = loop.cfg, loop.learner
    next_checkpoint = loop.step + cfg.checkpoint_every
    next_eval = (loop.step // cfg.eval_every + 1) * cfg.eval_every if cfg.eval_every > 0 else math.inf
    next_log = (loop.step // cfg.log_every + 1) * cfg.log_every
    last_eval_step = last_checkpoint_step = -1
    try:
        pool.publish(learner.flat_weights(), learner.updates, loop.epsilon())
        pool.start(list(loop.episodes_by_actor), loop.note)
        last_data = time.monotonic()
        while True:
            loop.learn(pool)
            finished = loop.step >= cfg.total_steps
            stopping = STOP.is_set() and not finished  # the first Ctrl-C: keep what was learned, resumable
            if loop.step >= next_log or finished:
                loop.log_actors(pool)
                next_log = (loop.step // cfg.log_every + 1) * cfg.log_every
            if cfg.eval_trajectories and not stopping and (loop.step >= next_eval or (finished and last_eval_step != loop.step)):
                learner.evaluate(loop.step)
                last_eval_step = loop.step
                while next_eval <= loop.step:
                    next_eval += cfg.eval_every
            if loop.step >= next_checkpoint or ((finished or stopping) and last_checkpoint_step != loop.step):
                learner.checkpoint(loop.state(), loop.replay)
                last_checkpoint_step, next_checkpoint = loop.step, loop.step + cfg.checkpoint_every
            if finished or stopping:
                break
            pool.set_epsilon(loop.epsilon())
            got = pool.poll(0.5, loop.episodes_by_actor, loop.note)
            if pool.alive() == 0:
                raise ClientError(f"every actor died (restarts: {loop.restarts_by_actor}); see the messages above")
            if not got:
                if time.monotonic() - last_data > STALL_TIMEOUT:
                    raise ClientError(f"no transitions from any of the {cfg.servers} actors for {STALL_TIMEOUT:.0f} s")
                continue
            last_data = time.monotonic()
            for i, batch in got:
                loop.ingest(i, batch)
                if loop.on_batch is not None:
                    loop.on_batch(loop.step, i, batch)
            loop.sps = (loop.step - loop.steps_at_start) / max(time.perf_counter() - loop.t_start, 1e-9)
            loop.show(pool)
        t_end = time.perf_counter()
        loop.show(pool, force=True)
    finally:
        loop.bar.close()
    return t_end


def _summary(loop: _StreamsLoop, learner: Learner, replay: StreamReplay, cfg: Config, t_end: float, use_ray: bool) -> dict[str, Any]:
    """What :func:`train_distributed` returns, from its loop, learner and replay at the end."""
    t0, s0 = loop.first_batch if loop.first_batch is not None else (t_end, loop.step)
    return {
        "steps": loop.step,
        "updates": learner.updates,
        "episodes": loop.episodes,
        "best_score": learner.best_score,
        "last_eval": learner.last_eval,
        "wall_s": t_end - loop.t_start,
        "env_steps_per_s": (loop.step - s0) / max(t_end - t0, 1e-9),
        "servers": cfg.servers,
        "backend": "ray" if use_ray else "local",
        "transitions_by_actor": list(loop.transitions_by_actor),
        "restarts_by_actor": [r - r0 for r, r0 in zip(loop.restarts_by_actor, loop.restarts_at_start, strict=True)],
        "actor_pids": sorted(loop.pids),
        "replay_bytes_per_transition": replay.nbytes / replay.capacity,
        "stopped": STOP.is_set() and loop.step < cfg.total_steps,  # a stop at the last step finished the run
    }
