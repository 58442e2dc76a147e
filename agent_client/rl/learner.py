"""The one learner of both trainers: networks, optimiser, seeding, the gradient step,
target sync, checkpoint and resume, evaluation.

The gradient step minimises a sum of named loss terms chosen once from the config (the
Double-DQN TD loss or a teacher's cross-entropy, then the auxiliary heads and the brake
margin): :mod:`agent_client.rl.losses`, one module per term.

The single-stream loop (:mod:`agent_client.rl.train`) and the K-stream loop
(:mod:`agent_client.rl.distributed`) only feed it. With the parallel schedule its
gradient steps run on a worker thread (the second core) while the loop acts; see
:meth:`Learner.train_step` for the schedule that keeps the run bit-identical.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import sys
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn as nn
from torch.nn.utils import parameters_to_vector

from agent_client.actions import is_continuous
from agent_client.controllers.acc import AccController, LateClosing
from agent_client.errors import InputFileError
from agent_client.outputs import write_text
from agent_client.rewards import CONTROL_PERIOD
from agent_client.rl import actor_critic as ac
from agent_client.rl.checkpoint import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    Lineage,
    atomic_save,
    checkpoint_config,
    load_policy,
    load_weights,
    make_lineage,
    read_checkpoint,
    save_policy,
)
from agent_client.rl.config import RESUMABLE_CHANGES, Config, config_dict
from agent_client.rl.evaluation import eval_episode, evaluate, score
from agent_client.rl.losses import Forward, build_terms, imitation, td, weighted_sum
from agent_client.rl.network import Decision, Policy, QNetwork, RecurrentQNetwork, transfer_weights
from agent_client.rl.replay import (
    ReplayMemory,
    ReplaySamples,
    SequenceSamples,
    StreamReplay,
    flat_transitions,
)
from agent_client.rl.scalars import ScalarLog
from agent_client.rl.stop import STOP
from agent_client.rl.teachers import teacher_law

__all__ = ["Learner", "UpdateLosses", "SESSION_TIMEOUT", "STOP"]

SESSION_TIMEOUT = 3600.0  # [s] spawned training servers keep an idle session this long
EVAL_PARALLEL = 4  # evaluation episodes run at once, each with its own server
MALLOC_KEEP = 1 << 30  # [B] freed memory glibc keeps for reuse instead of returning it to the OS


def keep_freed_memory() -> None:
    """Let glibc reuse freed blocks instead of mapping fresh pages for every tensor.

    An update allocates and frees tens of 4-16 MB temporaries (the float frames, the
    activations, the gradients). By default glibc maps each from the OS and unmaps it
    when freed, so every update pays its page faults again: about a third of its time
    on one core. Raising the mmap and trim thresholds keeps the blocks in the heap. The
    numbers computed are the same; only where the memory comes from changes.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if name is None:
        return
    try:
        libc = ctypes.CDLL(name)
        M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's <malloc.h>
        libc.mallopt(M_MMAP_THRESHOLD, 256 << 20)  # blocks below 256 MB come from the heap
        libc.mallopt(M_TRIM_THRESHOLD, MALLOC_KEEP)
    except (OSError, AttributeError):  # not glibc: keep its defaults
        pass


def thread_cap(threads: int) -> int:
    """``threads``, at most OMP_NUM_THREADS when that is a positive integer: processes that
    share cores (a test suite's workers, several trainings) set it, since torch's threads
    spin-wait and two processes of 2 threads each on 2 cores run twice as slow as 1 each."""
    try:
        cap = int(os.environ.get("OMP_NUM_THREADS", ""))
    except ValueError:
        return threads
    return min(threads, cap) if cap > 0 else threads


class UpdateLosses(NamedTuple):
    """What a logged gradient step reports (:meth:`Learner.update`)."""

    main: float  # the main term's loss (TD or teacher), without the others
    taken: float  # the mean output at the stored actions (Q-value, or the label's logit)
    terms: dict[str, float]  # each other term's own loss (unweighted), by its scalar name


def make_teacher(name: str, lag: float = 0.0) -> AccController | LateClosing | None:
    """The privileged teacher of a DAgger run (:data:`~agent_client.rl.teachers.REGISTRY`), or None.

    ``lag`` > 0 [s]: the law's following term sees the closing speed that late
    (:class:`~agent_client.controllers.acc.LateClosing`, ``Config.teacher_lag``).
    """
    if name == "none":
        return None
    if name == "policy":
        raise ValueError("the policy teacher is a network: PolicyTeacher(cfg), with cfg.teacher_policy")
    law = teacher_law(name)
    return LateClosing(law, lag, CONTROL_PERIOD) if lag > 0.0 else law


class PolicyTeacher:
    """A trained policy as the teacher of a DAgger run (``--teacher policy``): distillation.

    It decides on the student's own observation (frames, speeds, controls: nothing
    privileged) with its checkpoint's decision rule; the label is its action, or, for the
    mean decision, the level whose ramp brings the held force nearest its target (as a
    law's force is labelled). Where it drives, it drives as itself.

    Raises:
        InputFileError: an unreadable checkpoint, or one that observes or acts otherwise
            than ``cfg`` (frame stack, stride, zoom, action type, set speed).
    """

    def __init__(self, cfg: Config):
        path = str(cfg.teacher_policy)
        q, tcfg = load_policy(path)
        for name in ("frame_stack", "stack_stride", "zoom", "action", "speed_scale", "set_speed"):
            if getattr(tcfg, name) != getattr(cfg, name):
                raise InputFileError(f"{path}: the teacher's {name} is {getattr(tcfg, name)!r}, the student's {getattr(cfg, name)!r}: a teacher must observe and act as its student")
        self.policy = Policy.of(q, tcfg)

    def reset(self) -> None:
        """Start an episode (the decision rule's brake confirmation)."""
        self.policy.reset()

    def decide(self, obs: dict[str, Any], held: Any, hard_brake: float) -> tuple[Decision, int]:
        """Its decision on ``obs`` and the label in ``held``'s action type (the env's, which
        holds the student's force)."""
        d = self.policy(obs)
        return d, d.action if d.target is None else held.imitate(d.target, hard_brake)


class Learner:
    """Owns everything a training run learns with; the loops only feed it.

    Construction seeds python, numpy and torch (the one seeding block), builds the
    networks and the optimiser, then either resumes ``run_dir/latest.pt`` or starts
    from ``cfg.init_from``, writes ``config.json`` and opens the scalar log.

    Args:
        cfg: the settings.
        run_dir: ``runs/<name>``.
        resume: continue from ``run_dir/latest.pt``.
        trainer: "single" or "streams": which loop's checkpoints this run writes.
        server_args: extra ``python -m sim_server`` arguments for the evaluation server.
        on_eval: called with (step, results) after each evaluation.
        load_replay: (resume) restores the replay the checkpoint names; called before
            anything in ``run_dir`` is written, so that a bad file leaves the folder as it was.

    Attributes:
        rng: the numpy generator of replay sampling (and, in the serial schedule, of
            everything the loop draws).
        acting_rng: the loop's generator for episode seeds, ε and random actions.
        loss_terms: the named terms whose sum each gradient step minimises, main term first
            (:func:`~agent_client.rl.losses.build_terms`).
        saved: the loop state of the resumed checkpoint ({} for a new run).
        lineage: what every checkpoint of the run records it was made from (None: a
            resumed run whose ``latest.pt`` predates lineage, so unknown).
        replay_names: the replay files that go with it (then with the last checkpoint written).

    Raises:
        InputFileError: a bad checkpoint to resume or to start from.
    """

    def __init__(self, cfg: Config, run_dir: str | Path, *, resume: bool = False, trainer: str = "single",
                 server_args: tuple[str, ...] = (), on_eval: Callable[[int, list[dict[str, Any]]], None] | None = None,
                 load_replay: Callable[[Learner], None] | None = None):  # fmt: skip
        self.cfg, self.trainer, self.on_eval = cfg, trainer, on_eval
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.server_args = ("--session-timeout", str(SESSION_TIMEOUT), *server_args)
        self.parallel = cfg.schedule == "parallel" and trainer == "single"

        keep_freed_memory()

        # --- seeding: the one block. Everything random draws from these. -----------
        random.seed(cfg.seed)
        torch.manual_seed(cfg.seed)
        torch.backends.cudnn.deterministic = True
        torch.set_num_threads(thread_cap(cfg.torch_threads))
        self.rng = np.random.default_rng(cfg.seed)
        # The serial schedule draws everything from one generator (as the shipped models
        # were trained); the parallel one acts from its own, so sampling never races it.
        self.acting_rng = np.random.default_rng([cfg.seed, 1]) if self.parallel else self.rng
        self.device = torch.device("cuda" if cfg.cuda and torch.cuda.is_available() else "cpu")

        self.q = self._network()
        self.target = self._network()
        self.target.load_state_dict(self.q.state_dict())
        self.acting = self._network().eval() if self.parallel else self.q
        self.acting_policy = ac.policy_of(self.acting, cfg)
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
        # DAgger: the privileged teacher that labels states (teacher runs only)
        self.teacher = PolicyTeacher(cfg) if cfg.teacher == "policy" else make_teacher(cfg.teacher, cfg.teacher_lag)
        self.continuous = is_continuous(cfg.action)  # the actor-critic (DrQ-v2) instead of the Double DQN
        self._std = cfg.noise_start  # (actor-critic) the exploration noise's std at the step being learned
        self.loss_terms = () if self.continuous else build_terms(cfg, self.q, self.target, self.device)  # type: ignore[arg-type]
        self._main_name = ac.CRITIC_NAME if self.continuous else self.loss_terms[0].name
        self._taken_name = td.VALUES_NAME if self.teacher is None else imitation.LOGIT_NAME
        self.updates = 0
        self.best_score = math.inf
        self.saved: dict[str, Any] = {}
        self.replay_names: list[str] = []
        self.lineage: Lineage | None = None
        # (actor-critic, --bc-steps) the student drives until learning starts and is cloned then;
        # (--bc-weight) it anchors the actor's every step; loaded before a resume restores the generators, as building a network draws from torch's
        self.student = load_policy(str(cfg.init_from), self.device) if self.continuous and (cfg.bc_steps > 0 or cfg.bc_weight > 0.0) else None
        if resume:  # every check that can fail, before anything in the run folder is written
            self._resume()
            if load_replay is not None:
                load_replay(self)
            self._check_best()
        else:
            self._init_from()
            self.lineage = self._new_lineage()
        # (actor-critic, init_from a DQN) the clone of its decision runs before the first update
        self._bc_pending = self.continuous and cfg.bc_steps > 0 and self.updates == 0
        if self.parallel:
            if not resume:
                self.acting.load_state_dict(self.q.state_dict())
            # The worker needs the GIL between torch ops; at the default 5 ms switch
            # interval it would wait behind the acting thread's Python for most of a step.
            sys.setswitchinterval(1e-4)
            self._worker: ThreadPoolExecutor | None = ThreadPoolExecutor(1, thread_name_prefix="vacc-learner")
        else:
            self._worker = None
        self._jobs: list[Future[Any]] = []
        self._pending_scalars: list[tuple[str, float, int]] = []
        # The scalar log checks scalars.csv (a resume) before it or config.json is written.
        self.log = ScalarLog(self.run_dir, resume_step=self.saved.get("global_step") if resume else None, resume_episodes=self.saved.get("episodes"))  # fmt: skip
        try:
            write_text(self.run_dir / "config.json", json.dumps(config_dict(cfg), indent=2) + "\n")
        except BaseException:
            self.log.close()
            raise
        self.log.text("config", "```\n" + json.dumps(config_dict(cfg), indent=2) + "\n```")  # markdown in TensorBoard
        self.last_eval: list[dict[str, Any]] = []
        self._eval_env: Any = None

    def _network(self) -> QNetwork:
        return ac.network_of(self.cfg).to(self.device)  # type: ignore[return-value]

    # ------------------------------------------------------------------ start

    def _init_from(self) -> None:
        """Start both networks from ``cfg.init_from`` (fine-tuning), if set."""
        cfg = self.cfg
        if cfg.init_from is None:
            return
        init_q, init_cfg = load_policy(cfg.init_from)
        if (cfg.bc_steps > 0 or cfg.bc_weight > 0.0) and init_q.recurrent:
            raise InputFileError(f"{cfg.init_from}: a recurrent network cannot be the student of --bc-steps or --bc-weight (they read a frame-stack DQN's decision): "
                                 "give a frame-stack student")  # fmt: skip
        if (init_cfg.frame_stack, init_cfg.stack_stride, init_cfg.speed_scale, init_cfg.zoom) != (cfg.frame_stack, cfg.stack_stride, cfg.speed_scale, cfg.zoom):
            raise InputFileError(f"{cfg.init_from}: trained with another frame stack, stride, speed scale or zoom")
        widths = [(",".join(map(str, c.conv_channels)), c.hidden) for c in (init_cfg, cfg)]
        if widths[0] != widths[1]:
            (c0, h0), (c1, h1) = widths
            raise InputFileError(f"{cfg.init_from}: a network of {c0} channels and {h0} hidden units, this run's {c1} and {h1}: "
                                 "start from scratch, or learn from it with --teacher policy")  # fmt: skip
        if init_cfg.action == cfg.action and init_q.state_dict().keys() == self.q.state_dict().keys():
            self.q.load_state_dict(init_q.state_dict())
        elif isinstance(self.q, ac.RecurrentActorCritic):  # its trunk by name; its actor and critic afresh (or cloned)
            transfer_weights(ac.recurrent_start(init_q), self.q)
        else:  # another action set, a gap head added, or a DQN's trunk for the actor-critic (its actor cloned by bc_steps)
            transfer_weights(init_q, self.q)
        critic_conv = getattr(self.q, "critic_conv", None)
        if isinstance(critic_conv, nn.Module) and "critic_conv.0.weight" not in init_q.state_dict():
            critic_conv.load_state_dict(self.q.conv.state_dict())  # the critic's copy starts as the actor's trunk
        self.target.load_state_dict(self.q.state_dict())

    def _new_lineage(self) -> Lineage:
        """A new run's lineage: the files it starts from and learns from, hashed now, as they
        were read (a later step may overwrite what their paths name)."""
        cfg = self.cfg
        parents = {"init_from": cfg.init_from, "teacher_policy": cfg.teacher_policy if cfg.teacher == "policy" else None}
        named = {role: path for role, path in parents.items() if path is not None}
        return make_lineage("train", list(named.values()), list(named))

    def _resume(self) -> None:
        path = self.run_dir / "latest.pt"
        ckpt = read_checkpoint(path)
        if ckpt.get("kind") != "training":
            raise InputFileError(f"{path}: a policy-only checkpoint cannot be resumed")
        if ckpt["trainer"] != self.trainer:
            what = "K-stream trainer; resume it with --servers/--ray" if ckpt["trainer"] == "streams" else "single-stream trainer; resume it without --servers/--ray"
            raise InputFileError(f"{path}: written by the {what}")
        self._check_resume_config(ckpt, path)
        self.lineage = ckpt.get("lineage")
        load_weights(self.q, ckpt["model"], path)
        load_weights(self.target, ckpt["target"], path, "target")
        if self.parallel:
            load_weights(self.acting, ckpt.get("acting", {}), path, "acting")
        try:
            self.optimizer.load_state_dict(ckpt["optimizer"])
            rng = ckpt["rng"]
            self.rng.bit_generator.state = rng["numpy"]
            if self.parallel:
                self.acting_rng.bit_generator.state = rng["acting"]
            torch.set_rng_state(rng["torch"])
            if "python" in rng:
                random.setstate((rng["python_version"], tuple(rng["python"]), None))
            self.saved = dict(ckpt["state"])
            self.replay_names = list(ckpt["replay"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise InputFileError(f"{path}: incomplete training state ({type(exc).__name__}: {exc})") from None
        self.updates = int(self.saved.get("updates", 0))
        self.best_score = float(self.saved.get("best_score", math.inf))

    def _check_best(self) -> None:
        """A resumed run that has evaluated keeps ``best.pt``: it must read back, or a run
        that never beats it would end with a broken best.pt.

        Raises:
            InputFileError: missing or damaged.
        """
        if math.isfinite(self.best_score):
            path = self.run_dir / "best.pt"
            if not path.is_file():
                raise InputFileError(f"{path}: not found, but latest.pt's run kept its best evaluation there")
            read_checkpoint(path)

    def _check_resume_config(self, ckpt: dict[str, Any], path: Path) -> None:
        """A resumed run must have the saved run's settings, but for ``RESUMABLE_CHANGES``."""
        saved = checkpoint_config(ckpt, path)
        cfg = self.cfg
        if dataclasses.replace(saved, **{k: getattr(cfg, k) for k in RESUMABLE_CHANGES}) != cfg:
            diff = {k: (v, getattr(cfg, k)) for k, v in dataclasses.asdict(saved).items() if k not in RESUMABLE_CHANGES and v != getattr(cfg, k)}
            raise InputFileError(f"{path}: the run was trained with other settings; differences (saved, given): {diff}")

    # ------------------------------------------------------------------- acting

    def act(self, obs: dict[str, np.ndarray]) -> Decision:
        """The acting network's decision (one update behind in the parallel schedule)."""
        return self.acting_policy(obs)

    def flat_weights(self) -> np.ndarray:
        """The online network's parameters as one float32 vector on the CPU (2.8 MB)."""
        return parameters_to_vector(self.q.parameters()).detach().cpu().numpy().astype(np.float32, copy=False)

    # ------------------------------------------------------------------ learning

    def update(self, b: ReplaySamples | SequenceSamples, log_step: int | None = None) -> UpdateLosses | None:
        """One gradient step on a replay batch: the sum of :attr:`loss_terms`
        (:func:`~agent_client.rl.losses.weighted_sum`), clipped to ``cfg.max_grad_norm``.

        Returns:
            The step's losses when ``log_step`` is given (the loop logs them there).
        """
        if isinstance(b, SequenceSamples) and not bool(b.train.any()):  # every sequence still in its burn-in: nothing to learn from
            return None
        if self.continuous:
            return self._update_actor_critic(b, log_step)
        if isinstance(b, SequenceSamples):
            return self._update_recurrent(b, log_step)
        dev = self.device
        frames, speeds, controls = b.frames.to(dev), b.speeds.to(dev), b.controls.to(dev)
        q_all, gap_raw, closing_raw = self.q.with_heads(frames, speeds, controls)  # [B, A], [B] or None each
        q_taken = q_all.gather(1, b.actions.to(dev)[:, None]).squeeze(1)  # [B]
        total, values = weighted_sum(self.loss_terms, Forward(b, dev, q_all, q_taken, gap_raw, closing_raw))
        return self._step(total, values, q_taken, log_step)

    def _update_recurrent(self, seq: SequenceSamples, log_step: int | None) -> UpdateLosses | None:
        """One step on replayed sequences (R2D2): unroll the online and target networks from
        each sequence's stored state; the loss terms read the steps past the burn-in."""
        dev, cfg, net, target = self.device, self.cfg, self.q, self.target
        assert isinstance(net, RecurrentQNetwork) and isinstance(target, RecurrentQNetwork)
        frames, speeds, controls, states = seq.frames.to(dev), seq.speeds.to(dev), seq.controls.to(dev), seq.states.to(dev)
        q_all, gap_all, closing_all, _ = net.unroll(frames, speeds, controls, states)  # [B, L + 1, A]
        keep = seq.train.to(dev)  # [B, L]
        next_q = None
        if self.teacher is None:
            with torch.no_grad():
                target_all = target.unroll(frames, speeds, controls, states)[0]
            next_q = (q_all[:, 1:][keep].detach(), target_all[:, 1:][keep])
        q = q_all[:, :-1][keep]  # [N, A]
        flat = flat_transitions(seq, cfg.gamma)
        q_taken = q.gather(1, flat.actions.to(dev)[:, None]).squeeze(1)
        heads = [None if h is None else h[:, :-1][keep] for h in (gap_all, closing_all)]
        total, values = weighted_sum(self.loss_terms, Forward(flat, dev, q, q_taken, heads[0], heads[1], next_q))
        return self._step(total, values, q_taken, log_step)

    def _step(self, total: torch.Tensor, values: list[torch.Tensor], q_taken: torch.Tensor, log_step: int | None) -> UpdateLosses | None:
        self.optimizer.zero_grad()
        total.backward()
        nn.utils.clip_grad_norm_(self.q.parameters(), self.cfg.max_grad_norm)
        self.optimizer.step()
        self.updates += 1
        if log_step is None:
            return None
        others = {term.name: value.item() for term, value in zip(self.loss_terms[1:], values[1:], strict=True)}
        return UpdateLosses(values[0].item(), q_taken.mean().item(), others)

    def _sample(self, memory: ReplayMemory | StreamReplay) -> ReplaySamples | SequenceSamples:
        cfg = self.cfg
        if cfg.recurrent != "none":
            return memory.sample_sequences(cfg.batch_size, self.rng, cfg.sequence_length, cfg.burn_in)  # type: ignore[union-attr]
        return memory.sample(cfg.batch_size, self.rng, cfg.n_step, cfg.gamma)

    def _update_actor_critic(self, b: ReplaySamples | SequenceSamples, log_step: int | None) -> UpdateLosses | None:
        """One DrQ-v2 step (:func:`agent_client.rl.actor_critic.update`, or ``update_sequences``
        for the recurrent trunk), its noise at ``_std``; the actor learns from update ``critic_warmup`` on."""
        step = ac.update_sequences if isinstance(b, SequenceSamples) else ac.update
        actor = self.updates >= self.cfg.critic_warmup
        anchor = None
        if actor and self.cfg.bc_weight > 0.0:  # TD3+BC: the student's decision on the batch
            assert self.student is not None  # loaded with the learner
            anchor = ac.anchor_targets(self.q, *self.student, b, self.device)  # type: ignore[arg-type]
        losses = step(self.q, self.target, self.optimizer, b, self.cfg, self._std, self.device, log_step is not None, actor, anchor)  # type: ignore[arg-type]
        self.updates += 1
        if losses is None:
            return None
        return UpdateLosses(losses.critic, losses.q_values, {ac.ACTOR_NAME: losses.actor} | ({} if losses.bc is None else {ac.BC_NAME: losses.bc}))

    def _clone_student(self, memory: ReplayMemory | StreamReplay, step: int) -> None:
        """The behaviour-cloning warm start: ``bc_steps`` steps of the actor on the
        ``init_from`` student's decision on replayed frames; the mean error logged at ``step``."""
        assert self.student is not None  # bc_steps > 0: loaded with the learner
        student, student_cfg = self.student

        def batch() -> ReplaySamples | SequenceSamples:
            return self._sample(memory) if self.q.recurrent else memory.sample(self.cfg.batch_size, self.rng)

        errors = [ac.clone_student(self.q, self.optimizer, student, student_cfg, batch(),  # type: ignore[arg-type]
                                   self.device, self.cfg.max_grad_norm) for _ in range(self.cfg.bc_steps)]  # fmt: skip
        self.log.add(ac.BC_NAME, float(np.mean(errors)), step)
        self._bc_pending = False

    def sync_target(self) -> None:
        """Copy the online network into the target network (after any update in flight).
        The actor-critic's target follows by Polyak averaging in each update instead."""
        if self.continuous:
            return
        self._run(lambda: self.target.load_state_dict(self.q.state_dict()))

    def train_step(self, memory: ReplayMemory | StreamReplay, step: int) -> None:
        """The gradient step due at env step ``step``.

        Serial schedule: sample and update now. Parallel schedule: wait for the previous
        update, hand its weights to the acting network, sample (on this thread, so the
        batch holds exactly the transitions up to ``step``), and start the update on
        the worker thread; the loop acts the next ``train_every`` steps meanwhile. So
        the actor always acts with the weights of exactly one update ago, and the run
        is a function of the seed alone.
        """
        cfg = self.cfg
        log_step = step if step % cfg.log_every < cfg.train_every else None
        if self.continuous:
            self.wait()  # the clone and the noise of the step in flight come first
            if self._bc_pending:
                self._clone_student(memory, step)
                if self.parallel:
                    self.acting.load_state_dict(self.q.state_dict())
            self._std = ac.noise_std(cfg, step)
        if self._worker is None:
            self._log_losses(self.update(self._sample(memory), log_step), log_step)
            return
        self.wait()
        self.acting.load_state_dict(self.q.state_dict())
        batch = self._sample(memory)
        self._jobs.append(self._worker.submit(lambda: self._pending(self.update(batch, log_step), log_step)))

    def _pending(self, losses: UpdateLosses | None, step: int | None) -> None:
        if losses is not None and step is not None:  # logged by the loop's thread at the next wait()
            self._pending_scalars += [(self._main_name, losses.main, step), (self._taken_name, losses.taken, step)]
            self._pending_scalars += [(name, value, step) for name, value in losses.terms.items()]

    def _log_losses(self, losses: UpdateLosses | None, step: int | None) -> None:
        self._pending(losses, step)
        for name, value, at in self._pending_scalars:
            self.log.add(name, value, at)
        self._pending_scalars.clear()

    def _run(self, job: Callable[[], Any]) -> None:
        """Run ``job`` after the work already queued (now, in the serial schedule)."""
        if self._worker is None:
            job()
        else:
            self._jobs.append(self._worker.submit(job))

    def wait(self) -> None:
        """Finish the queued gradient steps (re-raising their errors) and log their scalars."""
        jobs, self._jobs = self._jobs, []
        for job in jobs:
            job.result()
        self._log_losses(None, None)

    # --------------------------------------------------------------- evaluation

    def evaluate(self, step: int) -> list[dict[str, Any]]:
        """Greedy episodes on ``cfg.eval_trajectories``; keeps ``best.pt``; returns the results."""
        from agent_client.env import VisionACCEnv  # the env spawns a server; import late

        cfg = self.cfg
        self.wait()
        if self._eval_env is None:
            self._eval_env = []
        while len(self._eval_env) < min(len(cfg.eval_trajectories), EVAL_PARALLEL):  # an env (and server) per episode run at once
            self._eval_env.append(VisionACCEnv(
                scenario=cfg.scenario, trajectory=eval_episode(cfg.eval_trajectories[0])[0], reward=cfg.reward,
                frame_stack=cfg.frame_stack, stack_stride=cfg.stack_stride,
                episode_seconds=cfg.eval_seconds, server_args=self.server_args, zoom=cfg.zoom, set_speed=cfg.set_speed,
                action=cfg.action, eco_weights=cfg.eco_weights, crash_reward=cfg.crash_reward, preroll=cfg.preroll,
            ))  # fmt: skip
        self.q.eval()
        self.last_eval = evaluate(ac.policy_of(self.q, cfg), self._eval_env, cfg.eval_trajectories)
        self.q.train()
        s = score(self.log, self.last_eval, step)
        if s < self.best_score:
            self.best_score = s
            save_policy(self.q, cfg, self.run_dir / "best.pt", {"step": step, "eval": self.last_eval}, self.lineage)
        if cfg.keep_evals:
            (self.run_dir / "evals").mkdir(exist_ok=True)
            save_policy(self.q, cfg, self.run_dir / "evals" / f"{step}.pt", {"step": step, "eval": self.last_eval}, self.lineage)
        self.log.flush()
        if self.on_eval is not None:
            self.on_eval(step, self.last_eval)
        return self.last_eval

    # -------------------------------------------------------------- checkpoints

    def checkpoint(self, state: dict[str, Any], memory: ReplayMemory | StreamReplay) -> None:
        """Write ``latest.pt`` with the loop's ``state`` and the replay that goes with it.

        The replay first, under new names; then ``latest.pt``, which names them; only
        then the old replay files go. A kill -9 anywhere leaves a resumable pair; a failed
        or interrupted write (a second Ctrl-C) removes the new replay files it wrote.

        Raises:
            CheckpointWriteError: a write failed; the previous checkpoint still resumes.
        """
        self.wait()
        self.log.flush()  # the rows up to this step reach the file before latest.pt counts them
        step = int(state["global_step"])
        names = memory.file_names(step) if isinstance(memory, StreamReplay) else [f"replay-{step}.npz"]
        try:
            self._write_checkpoint(state, memory, step, names)
        except BaseException:  # none of them is named by a latest.pt
            for name in set(names) - set(self.replay_names):
                (self.run_dir / name).unlink(missing_ok=True)
            raise
        self.replay_names = names
        for old in [*self.run_dir.glob("replay-*.npz"), self.run_dir / "replay.npz"]:
            if old.name not in names and old.exists():
                old.unlink()
        self.log.flush()

    def _write_checkpoint(self, state: dict[str, Any], memory: ReplayMemory | StreamReplay, step: int, names: list[str]) -> None:
        if isinstance(memory, StreamReplay):
            memory.save(self.run_dir, step)
        else:
            memory.save(self.run_dir / names[0], step)
        rng: dict[str, Any] = {
            "numpy": self.rng.bit_generator.state,
            "torch": torch.get_rng_state(),
            "python": list(random.getstate()[1]),
            "python_version": random.getstate()[0],
        }
        if self.parallel:
            rng["acting"] = self.acting_rng.bit_generator.state
        payload: dict[str, Any] = {
            "format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "kind": "training", "trainer": self.trainer,
            "config": config_dict(self.cfg), "model": self.q.state_dict(), "target": self.target.state_dict(),
            "optimizer": self.optimizer.state_dict(), "replay": names, "rng": rng,
            "state": {**state, "updates": self.updates, "best_score": self.best_score},
        }  # fmt: skip
        if self.parallel:
            payload["acting"] = self.acting.state_dict()
        if self.lineage is not None:
            payload["lineage"] = self.lineage
        atomic_save(payload, self.run_dir / "latest.pt")

    def close(self) -> None:
        """Stop the worker, close the log and the evaluation server. Safe to call twice."""
        try:
            if self._worker is not None:
                self._worker.shutdown(wait=True, cancel_futures=True)
                self._worker = None
        finally:
            self.log.close()
            for env in self._eval_env or []:
                env.close()
            self._eval_env = None
