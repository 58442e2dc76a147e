"""The settings of a training run: one frozen dataclass, one docstring per field.

``vacc train`` generates its options from these fields (:mod:`agent_client.rl.cli`),
so the docstrings below are the ``--help`` text and the defaults are the CLI's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from agent_client.actions import ACTION_TYPES, RAMP_ACTIONS
from agent_client.errors import InputFileError
from agent_client.preprocess import ZOOMS
from agent_client.rewards import ECO_WEIGHTS, check_eco_weights
from agent_client.rl.evaluation import eval_episode
from agent_client.rl.teachers import TEACHERS
from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE, TRAFFIC_PER_LANE_RANGE
from protocol.scenarios import (
    DEFAULT_SET_SPEED,
    LEAD_SCENARIOS,
    RANDOM,
    SET_SPEED_RANGE,
    TEST_TRAJECTORIES,
    check_sun_elevation,
)

__all__ = ["Config", "ConfigError", "DECISIONS", "SCHEDULES", "TEACHERS", "RESUMABLE_CHANGES", "config_dict", "config_from"]

SCHEDULES = ("parallel", "serial")
DECISIONS = ("argmax", "mean")  # how the network's outputs become the force (agent_client.rl.network.Policy)

# Settings a resumed run may change: none of them touches the training RNG or the
# learning (evaluations and checkpoints draw nothing from it), so a run resumed with
# other values stays bit-identical to one that never stopped.
RESUMABLE_CHANGES = ("total_steps", "eval_every", "checkpoint_every", "log_every", "keep_evals")

CRASH_REWARD_RANGE = (-10.0, 0.0)  # the floor of the normalised rewards is -1; a crash may cost more, never gain

# What a run saved before a setting existed did: it trained and evaluated that way.
LEGACY_VALUES = {"schedule": "serial", "set_speed": SET_SPEED_RANGE[1], "action": "levels", "teacher": "none", "teacher_brake": 0.0, "eco_weights": (1.0, 0.5, 0.25, 0.0)}


class ConfigError(ValueError):
    """A setting out of range; ``field`` names it (the CLI maps it to its option)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


def single_stream_only(cfg: Config) -> tuple[str, str] | None:
    """What in ``cfg`` only the single-stream trainer honours: (the first such field, a
    one-line message naming every one), or None.

    The K-stream trainer (``servers > 1``, or ``--ray`` with any number of servers) runs
    Double DQN over the force levels on random leads, with cold starts. Config refuses
    these with ``servers > 1``; the CLI and ``train_distributed`` also with ``--ray``.
    """
    found = [
        (field, option, reason)
        for wanted, field, option, reason in (
            (cfg.teacher != "none", "teacher", f"--teacher {cfg.teacher}", "labels no actions"),
            (cfg.aux_gap > 0.0, "aux_gap", f"--aux-gap {cfg.aux_gap:g}", "stores no gaps"),
            (cfg.aux_closing > 0.0, "aux_closing", f"--aux-closing {cfg.aux_closing:g}", "stores no gaps"),
            (cfg.brake_margin > 0.0, "brake_margin", f"--brake-margin {cfg.brake_margin:g}", "stores no gaps"),
            (cfg.preroll, "preroll", "--preroll", "starts its episodes cold"),
            (cfg.action != "levels", "action", f"--action {cfg.action}", "stores no controls"),
            (cfg.train_traffic != TRAFFIC_PER_LANE, "train_traffic", f"--train-traffic {cfg.train_traffic}", "spawns servers with the default traffic"),
            (tuple(cfg.train_sun_elevation) != SUN_ELEVATION, "train_sun_elevation", "--train-sun-elevation", "spawns servers with the default sun"),
            (tuple(cfg.train_trajectories) != (RANDOM,), "train_trajectories", f"--train-trajectories {','.join(cfg.train_trajectories)}", "drives random leads only"),
        )
        if wanted
    ]  # fmt: skip
    if not found:
        return None

    def listed(items: list[str]) -> str:
        return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"

    options, reasons = listed([o for _, o, _ in found]), listed([r for *_, r in found])
    verb = "needs" if len(found) == 1 else "need"
    return found[0][0], f"{options} {verb} the single-stream trainer (servers=1, without --ray): the K-stream trainer {reasons}"


@dataclass(frozen=True)
class Config:
    """Every setting of a training run. The CLI only fills this in."""

    reward: str = "gap"
    """Reward: "gap" (Table 1, gap term only), "force" (gap + force terms), or "eco" (gap term
    minus the host's energy and jerk; agent_client/rewards.py)."""
    scenario: str = "ice"
    """Simulator scenario: "ice" (eq. 7 lead trajectories) or "ev" (real traces)."""
    set_speed: float = DEFAULT_SET_SPEED
    """[m/s] cruise set speed of training and evaluation episodes: the host's speed limiter
    holds it (docs/scenarios.md). Runs from before the limiter are repeated with 80."""
    eco_weights: tuple[float, ...] = ECO_WEIGHTS
    """Weights of the eco reward's terms: gap, energy, comfort, closing speed
    (agent_client/rewards.py; the ablation that chose them is in docs/training.md)."""
    action: str = "levels"
    """Action type (agent_client/actions.py): "levels", the paper's 21 force levels; "steps",
    increments of a held force, fine near zero; "ramp", the 21 levels as targets of a
    rate-limited held force; or "ramp-fine", the ramp with 21 targets dense near zero. The
    last three observe the held force and the set speed."""
    train_trajectories: tuple[str, ...] = ("random",)
    """Comma-separated lead trajectories of training episodes, one drawn per episode (repeat a
    name to weight it): "random" (the scenario's generator) and lead scenarios such as stopped,
    brake-stop, catch-up (docs/scenarios.md); each with a fresh seed from the run's RNG."""
    train_traffic: int = TRAFFIC_PER_LANE
    """Cars in each adjacent lane (twice as many oncoming) of training episodes: the spawned
    training server's --traffic. Neighbours and their shadows are what a camera student may
    mistake for a threat, and a teacher's labels ignore them; more of them teach it to. The
    evaluation episodes (best.pt) keep the server's default, as vacc drive and vacc evaluate."""
    train_sun_elevation: tuple[float, ...] = SUN_ELEVATION
    """Range [rad] the sun's height is drawn from in training episodes: the spawned training
    server's --sun-elevation (LOW,HIGH). A low sun from the side throws the shadows of trees
    and buildings across the lane as dark bands, which a camera student may read as a car;
    a lower range shows it more of them. Evaluations keep the server's default."""
    total_steps: int = 200_000
    """Environment steps (control periods of 0.1 s) to train for, in total."""
    seed: int = 1
    """Seeds numpy, torch, python random and the stream of episode seeds."""
    schedule: str = "serial"
    """"serial": act, then take the gradient step, which uses torch_threads cores (on this
    2-core machine the fastest: docs/training.md). "parallel": the gradient step runs on a
    second thread while the loop acts the next train_every steps with the weights of exactly
    one update ago (bit-identical for a seed; for a learner on a GPU, where acting dominates)."""
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
    """ε after exploration_steps."""
    exploration_steps: int = 60_000
    """Steps over which ε falls linearly (absolute, so a resumed run keeps its schedule)."""
    learning_starts: int = 5_000
    """Steps of acting before the first gradient step."""
    train_every: int = 4
    """Environment steps per gradient step."""
    max_grad_norm: float = 10.0
    """Gradient norm clip."""
    n_step: int = 1
    """Rewards summed before bootstrapping (n-step return, cut at episode ends)."""
    absorbing_terminal: bool = True
    """Value a termination (collision, gap > 300 m) as its reward forever, r / (1 - γ),
    instead of 0: with Table 1's rewards, 0 would make crashing or dropping back past
    300 m look better than a long stretch of small negative rewards."""
    crash_reward: float | None = None
    """The reward of a collision (a termination, so with absorbing_terminal valued forever),
    in [-10, 0]: None, the reward's own value at contact. Table 1's force reward gives contact
    -10 plus the force term, so coasting into a car scores 0 for ever, better than braking
    hard (|u| > 0.3 earns no force term) and stopping short; -1, the floor of every reward,
    makes a crash the worst outcome. Its gap reward values a touch (-1) hardly below standing
    1 m short (-0.97); below -1 a touch costs clearly more than the near miss."""
    frame_stack: int = 8
    """Frames (and host speeds) per observation (paper: 8)."""
    stack_stride: int = 2
    """Control steps between stacked frames (2: the stack spans 1.4 s)."""
    preroll: bool = False
    """Start every training and evaluation episode after the camera pre-roll the stack spans
    ((frame_stack - 1) x stack_stride control steps, the host coasting), as vacc drive and
    vacc evaluate start a policy (docs/scenarios.md). Off: the first frame stands for the
    whole stack, as in the runs before protocol 4."""
    speed_scale: float = 30.0
    """[m/s] host speeds are divided by this before the network."""
    conv_channels: tuple[int, ...] = (16, 32, 64)
    """Output channels of the network's three convolutions (the shipped models': 16,32,64).
    Narrower layers decide faster (docs/benchmarks.md: 8,16,32 with --hidden 128 is a quarter
    of the arithmetic); a network of another width starts from scratch or is distilled
    (--teacher policy), since --init-from needs the same shapes."""
    hidden: int = 256
    """Units of the network's hidden fully connected layer (the shipped models': 256)."""
    zoom: int = 1
    """Camera window: 1, the paper's (the 400x400 camera halved); 2, the same 105x150
    window at full resolution (the lead at 55 m twice as wide). Checkpoints record it."""
    episode_seconds: float | None = 60.0
    """[s] training episodes are truncated here (0 or None: the trajectory's 240 s)."""
    eval_every: int = 25_000
    """Steps between evaluations on eval_trajectories (0: only at the end)."""
    eval_trajectories: tuple[str, ...] = TEST_TRAJECTORIES
    """Comma-separated evaluation trajectories; they pick best.pt: test-1..test-4 (seed 0,
    as vacc drive uses), random:SEED for a selection set held out from the tests, or a lead
    scenario[:SEED] (docs/scenarios.md)."""
    eval_seconds: float | None = None
    """[s] evaluation episode length (0 or None: the whole 240 s trajectory)."""
    keep_evals: bool = False
    """Also keep every evaluation's policy as evals/<step>.pt (each the size of best.pt), to
    choose between them later on other episodes (the safety suite's seeds)."""
    checkpoint_every: int = 10_000
    """Steps between full checkpoints (taken at the next episode end)."""
    init_from: str | None = None
    """A policy checkpoint whose weights start the run (fine-tuning, e.g. force from gap)."""
    teacher: str = "none"
    """"none": Double DQN on the reward. "policy": the decisions of --teacher-policy, a
    trained network seeing the same frames (distillation; nothing privileged). "acc": learn from a privileged teacher instead
    (DAgger, docs/training.md): the traditional ACC, which reads the gap and the lead's
    speed, labels every visited state with the action nearest its force; the network,
    from pixels as ever, learns the labels by cross-entropy. "acc-55": the same ACC law
    aiming at the paper's 55 m at every speed instead of its 1.8 s time gap, with gains
    that hold it (beta 0.3, gamma 1.0). "acc-55-gentle": the 55 m law with beta 0.4, gamma
    2.0 and its braking capped at 3 m/s^2 (the collision-avoidance limit brakes harder):
    6 % less energy than acc-55 through the ramp on random EV leads; "acc-55-gentle-margin": the
    same, stopping 3 m further back (as "eco-margin" below). "acc-55-eco(-margin)": the gentle
    law with gamma 3.0, matching the lead's speed harder: 0.7 % less energy through the ramp
    on random EV leads, worst gap RMSE 4.95 m against 4.79 m. "acc-55-calm(-margin)" and
    "acc-55-calmer(-margin)": the gentle law with lower gains (beta 0.3 and 0.25, gamma 1.5),
    which lose less energy than it when the lead's speed is seen half a second late, as a
    student sees it. "eco": the ACC law on the eco reward's desired gap,
    clip(2 s x speed, 5 m, 55 m), with gentler gains (beta 0.1, gamma 0.3): 3 % less fuel
    than the ACC on random ICE leads. "eco-margin": the eco teacher stopping 8 m behind a
    standing car and aiming 6 m behind a slower one (the ACC: 5 m and 3 m), so that a
    student a few frames late still stops short. "eco-firm(-margin)": the eco law with beta
    0.15, opening the gap from a close start faster for 1.7 % more fuel. "eco-mid(-margin)":
    beta 0.125, between the two (on random ICE leads 300-307 through the ramp: 2.5 % under
    the ACC's fuel at a worst gap RMSE of 3.20 m; eco 3.5 % at 3.33 m, eco-firm 1.3 % at 3.08 m)."""
    teacher_policy: str | None = None
    """(--teacher policy) the policy checkpoint whose decisions label the states: policy
    distillation, e.g. into a narrower network (--conv-channels, --hidden). The teacher sees
    what the student sees (frames, speeds, controls), so nothing privileged; it must
    observe the same way (frame stack, stride, zoom, action type, set speed)."""
    teacher_brake: float = 3.5
    """[m/s^2] (teacher, ramp action) the full brake, which acts at once and is released
    only at the ramp's rate, is a label only where the teacher decelerates at least this
    hard: ISO 15622's comfort limit. 0: wherever it is the nearest force."""
    brake_weight: float = 1.0
    """(teacher) weight of the cross-entropy where the label is the full brake: the few
    frames that decide a stop behind a standing car, among thousands of following states
    (1: unweighted, as every run before 2026-11-26)."""
    aux_gap: float = 0.0
    """Weight of an auxiliary loss: a second head on the network's hidden layer estimates the
    gap from the same frames and speeds (the log of gap / 55 m, the gap clipped to
    [1, 150] m, so 8 m against 12 m counts as much as 55 m against 82 m). The gap is
    privileged: it is the head's training target, stored beside the replay, and never an
    input; the Q-values (or the student's outputs) do not read the head. 0: no head, as
    every run before it. vacc drive logs the estimate (gap_est) of a model that has one."""
    aux_closing: float = 0.0
    """Weight of an auxiliary loss like aux_gap's: a head estimates the closing speed, the gap's
    fall over the next control step [m/s] (the lead's speed relative to the host's, which
    the frames show only as a change of size over the stack), clipped to +-20 m/s and
    scaled by 5 m/s, with the Huber loss. Privileged in the same way: a target stored
    beside the replay, never an input. vacc drive logs the estimate (closing_est). 0: off."""
    brake_margin: float = 0.0
    """(Double DQN) weight of a large-margin loss on the full brake (DQfD's, margin
    :data:`~agent_client.rl.learner.BRAKE_MARGIN`) in the replayed states where only a hard
    brake still stops :data:`~protocol.constants.MIN_GAP` short at the lead's speed: the
    closing speed, from the stored gaps one step apart, needs
    :data:`~agent_client.rl.learner.EMERGENCY_SHARE` of the full brake's deceleration or more.
    Beside the TD loss, it ranks the full brake first in the rare states that decide a
    collision, which the TD targets reach only through a few crashes. The gap is privileged:
    a training signal, stored beside the replay as for aux_gap, never an input. 0: off."""
    teacher_lag: float = 0.0
    """[s] (teacher) the teacher's following term sees the closing speed (host minus lead
    speed) through a first-order lag of this, as a student that reads it from its frame
    stack does (about 0.5 s); its collision-avoidance limit still reads the true speeds.
    Its following labels are then ones the student can reproduce. 0: as it is, as every
    run before the thirteenth session."""
    teacher_steps: int = 50_000
    """(teacher) steps over which the share of steps the teacher drives (DAgger's beta)
    falls linearly from 1 to 0; the student drives the rest, greedy but for epsilon."""
    decision: str = "argmax"
    """How the outputs become the force, in training, evaluation and vacc drive alike (the
    checkpoint records it): "argmax", the action with the largest output; "mean", for a
    teacher run with a ramp action: the held force ramps toward the mean of the target
    levels weighted by the softmax of the outputs, so a student torn between two levels
    asks for the force between them instead of flipping (the full brake still acts at
    once where it is the argmax, and where the argmax brakes firmly the target brakes no
    softer)."""
    decision_temperature: float = 2.0
    """(decision mean) the softmax's temperature over the outputs: higher averages over
    more levels."""
    decision_brake_share: float = 1.0
    """(decision mean) the full brake also acts at once where that softmax gives it at least
    this share, though another level is the argmax: a student unsure whether a closing car
    needs the full brake brakes fully, since a late full brake costs metres and an early
    one a second of comfort. 1: only where it is the argmax."""
    decision_brake_confirm: int = 1
    """(decision mean) decisions in a row whose softmax must give the full brake at least
    ``decision_brake_share`` before the share alone brakes fully (the argmax's full brake
    still acts at once). A camera student's phantom brake is often one decision long, but
    the ramp releases it at RAMP_RATE a step, so it costs 2.5 s of braking; a second
    decision in a row confirms a real threat 0.1 s later. 1: at once."""
    decision_full_brake_confirm: int = 1
    """(decision mean) decisions in a row whose argmax must be the full brake before it acts
    at once; until then the held force ramps toward it (RAMP_RATE a step). A narrow
    student's phantom brake was its argmax for one decision only (docs/training.md, r40),
    and a full brake is released at RAMP_RATE a step, so one false decision costs 2.5 s of
    braking; a second in a row brakes fully 0.1 s later. 1: at once."""
    decision_deadband: float = 0.0
    """(decision mean) where the mean's target lies within this much force of the held one,
    the held force stays (a brake of FIRM_BRAKE or more is never held back). An ablation:
    on random EV seeds 200-207 ev-eco saved no energy with 0.01-0.04 (docs/training.md).
    0: off."""
    decision_smoothing: float = 1.0
    """(decision mean) the share of the way from the held force to the mean's target that
    each step asks of the ramp: a first-order lag of time constant about one step over this
    share, against a student's target wandering over a second or two (a brake of FIRM_BRAKE
    or more is never lagged). 1: off."""
    torch_threads: int = 2
    """CPU threads of torch's operations: 2, the update's convolutions on both cores (on this
    machine the weights are bit-identical to one thread's)."""
    cuda: bool = True
    """Use CUDA when it is available."""
    log_every: int = 500
    """Steps between loss/Q-value scalars."""
    servers: int = 1
    """Simulator servers, each with its own acting process, feeding one learner
    (docs/scale-out.md). 1: the single-stream loop."""
    weight_sync_every: int = 20
    """(servers > 1) gradient steps between broadcasts of the learner's weights to the
    actors (M)."""
    actor_batch: int = 50
    """(servers > 1) transitions an actor collects per delivery to the learner."""

    def __post_init__(self) -> None:
        for check in SECTION_CHECKS.values():
            check(self)
        check_across_sections(self)

    @property
    def stores_gaps(self) -> bool:
        """Whether the replay keeps each observation's gap: the privileged target of the
        auxiliary heads and the brake margin's emergencies, never an input."""
        return self.aux_gap > 0.0 or self.aux_closing > 0.0 or self.brake_margin > 0.0


# Which fields each section of the settings holds; every field is in one, and each
# section's check reads only its own fields (check_across_sections reads several).
SECTIONS: dict[str, tuple[str, ...]] = {
    "environment": ("reward", "scenario", "set_speed", "eco_weights", "action", "train_trajectories", "train_traffic",
                    "train_sun_elevation", "crash_reward", "episode_seconds"),
    "dqn": ("total_steps", "seed", "schedule", "learning_rate", "adam_eps", "buffer_size", "gamma", "target_sync_every",
            "batch_size", "start_e", "end_e", "exploration_steps", "learning_starts", "train_every", "max_grad_norm",
            "n_step", "absorbing_terminal", "checkpoint_every", "init_from", "torch_threads", "cuda", "log_every"),
    "network": ("frame_stack", "stack_stride", "preroll", "speed_scale", "conv_channels", "hidden", "zoom"),
    "evaluation": ("eval_every", "eval_trajectories", "eval_seconds", "keep_evals"),
    "teacher": ("teacher", "teacher_policy", "teacher_brake", "brake_weight", "teacher_lag", "teacher_steps"),
    "auxiliary": ("aux_gap", "aux_closing", "brake_margin"),
    "decision": ("decision", "decision_temperature", "decision_brake_share", "decision_brake_confirm",
                 "decision_full_brake_confirm", "decision_deadband", "decision_smoothing"),
    "streams": ("servers", "weight_sync_every", "actor_batch"),
}  # fmt: skip


def _bad(name: str, message: str) -> ConfigError:
    return ConfigError(name, f"{name} {message}")


def _at_least(cfg: Config, names: tuple[str, ...], low: int) -> None:
    """Raises ConfigError: the first of ``names`` below ``low``."""
    for name in names:
        if getattr(cfg, name) < low:
            raise _bad(name, f"must be >= {low}")


def _finite_and_not_negative(cfg: Config, names: tuple[str, ...]) -> None:
    """Raises ConfigError: the first of ``names`` that is not finite and >= 0."""
    for name in names:
        if not (math.isfinite(getattr(cfg, name)) and getattr(cfg, name) >= 0.0):
            raise _bad(name, f"must be finite and >= 0, got {getattr(cfg, name)}")


def check_environment(cfg: Config) -> None:
    """The reward, scenario, action and training episodes. Raises ConfigError."""
    from agent_client.rewards import REWARDS

    if cfg.reward not in REWARDS:
        raise _bad("reward", f"{cfg.reward!r} is not one of {sorted(REWARDS)}")
    if cfg.scenario not in ("ice", "ev"):
        raise _bad("scenario", f"{cfg.scenario!r} is not 'ice' or 'ev'")
    if (why := check_eco_weights(tuple(cfg.eco_weights))) is not None:
        raise _bad("eco_weights", why)
    low, high = CRASH_REWARD_RANGE
    if cfg.crash_reward is not None and not low <= cfg.crash_reward <= high:
        raise _bad("crash_reward", f"must be in [{low:g}, {high:g}], got {cfg.crash_reward}")
    low, high = TRAFFIC_PER_LANE_RANGE
    if not low <= cfg.train_traffic <= high:
        raise _bad("train_traffic", f"must be in [{low}, {high}] cars a lane, got {cfg.train_traffic}")
    if (why := check_sun_elevation(tuple(cfg.train_sun_elevation))) is not None:
        raise _bad("train_sun_elevation", why)
    if cfg.action not in ACTION_TYPES:
        raise _bad("action", f"{cfg.action!r} is not one of {ACTION_TYPES}")
    if not cfg.train_trajectories:
        raise _bad("train_trajectories", "must name at least one trajectory")
    for name in cfg.train_trajectories:
        if name != RANDOM and name not in LEAD_SCENARIOS:
            raise _bad("train_trajectories", f"{name!r} is not {RANDOM!r} or a lead scenario ({', '.join(LEAD_SCENARIOS)})")
    if not SET_SPEED_RANGE[0] <= cfg.set_speed <= SET_SPEED_RANGE[1]:
        raise _bad("set_speed", f"must be in {SET_SPEED_RANGE[0]:g}..{SET_SPEED_RANGE[1]:g} m/s")


def check_dqn(cfg: Config) -> None:
    """The Double DQN's schedule, sizes and rates. Raises ConfigError."""
    if cfg.schedule not in SCHEDULES:
        raise _bad("schedule", f"{cfg.schedule!r} is not one of {SCHEDULES}")
    _at_least(cfg, ("total_steps", "n_step", "buffer_size", "batch_size", "train_every", "target_sync_every",
                    "torch_threads", "exploration_steps", "checkpoint_every", "log_every"), 1)  # fmt: skip
    _at_least(cfg, ("learning_starts",), 0)
    if not 0.0 <= cfg.gamma < 1.0:
        raise _bad("gamma", "must be in [0, 1)")
    for name in ("start_e", "end_e"):
        if not 0.0 <= getattr(cfg, name) <= 1.0:
            raise _bad(name, "must be in [0, 1]")
    if not cfg.learning_rate > 0.0:
        raise _bad("learning_rate", "must be > 0")


def check_network(cfg: Config) -> None:
    """What the network sees and its widths. Raises ConfigError."""
    if len(cfg.conv_channels) != 3 or not all(isinstance(c, int) and 1 <= c <= 512 for c in cfg.conv_channels):
        raise _bad("conv_channels", f"must be three whole numbers in 1..512, got {','.join(map(str, cfg.conv_channels))}")
    if not 1 <= cfg.hidden <= 4096:
        raise _bad("hidden", f"must be in 1..4096, got {cfg.hidden}")
    _at_least(cfg, ("frame_stack", "stack_stride"), 1)
    if cfg.zoom not in ZOOMS:
        raise _bad("zoom", f"must be one of {ZOOMS}")


def check_evaluation(cfg: Config) -> None:
    """The evaluations that pick best.pt. Raises ConfigError."""
    _at_least(cfg, ("eval_every",), 0)
    for name in cfg.eval_trajectories:
        try:
            eval_episode(name)  # a typo fails here, not at the first evaluation hours later
        except ValueError as exc:
            raise ConfigError("eval_trajectories", str(exc)) from None


def check_teacher(cfg: Config) -> None:
    """The teacher (DAgger) run's labels. Raises ConfigError."""
    if cfg.teacher not in TEACHERS:
        raise _bad("teacher", f"{cfg.teacher!r} is not one of {TEACHERS}")
    if (cfg.teacher == "policy") != (cfg.teacher_policy is not None):
        raise _bad("teacher_policy", "is the checkpoint of --teacher policy: give both or neither")
    if not cfg.teacher_brake >= 0.0:
        raise _bad("teacher_brake", "must be >= 0")
    if not cfg.brake_weight > 0.0:
        raise _bad("brake_weight", "must be > 0")
    if cfg.brake_weight != 1.0 and cfg.teacher == "none":
        raise _bad("brake_weight", "weights a teacher's labels: it needs a teacher (Double DQN has no labels)")
    if not (math.isfinite(cfg.teacher_lag) and cfg.teacher_lag >= 0.0):
        raise _bad("teacher_lag", f"must be finite and >= 0 s, got {cfg.teacher_lag}")
    if cfg.teacher_lag > 0.0 and cfg.teacher == "policy":
        raise _bad("teacher_lag", "delays a law's view of the closing speed: a policy teacher sees the frames as they are")
    if cfg.teacher_lag > 0.0 and cfg.teacher == "none":
        raise _bad("teacher_lag", "delays a teacher's view of the closing speed: it needs a teacher")
    _at_least(cfg, ("teacher_steps",), 1)


def check_auxiliary(cfg: Config) -> None:
    """The auxiliary heads' and the brake margin's weights. Raises ConfigError."""
    _finite_and_not_negative(cfg, SECTIONS["auxiliary"])


def check_decision(cfg: Config) -> None:
    """How the outputs become the force. Raises ConfigError."""
    if cfg.decision not in DECISIONS:
        raise _bad("decision", f"{cfg.decision!r} is not one of {DECISIONS}")
    if not cfg.decision_temperature > 0.0:
        raise _bad("decision_temperature", "must be > 0")
    for name, value, ok, text in (
        ("decision_brake_share", cfg.decision_brake_share, 0.0 < cfg.decision_brake_share <= 1.0, "in (0, 1]"),
        ("decision_deadband", cfg.decision_deadband, 0.0 <= cfg.decision_deadband < 0.5, "in [0, 0.5)"),
        ("decision_smoothing", cfg.decision_smoothing, 0.0 < cfg.decision_smoothing <= 1.0, "in (0, 1]"),
        ("decision_brake_confirm", cfg.decision_brake_confirm, cfg.decision_brake_confirm >= 1, ">= 1"),
        ("decision_full_brake_confirm", cfg.decision_full_brake_confirm, cfg.decision_full_brake_confirm >= 1, ">= 1"),
    ):  # fmt: skip
        if not ok:
            raise _bad(name, f"must be {text}, got {value}")
    if cfg.decision_brake_confirm > 1 and cfg.decision_brake_share >= 1.0:
        raise _bad("decision_brake_confirm", "confirms the brake share's full brake: it needs decision_brake_share below 1")
    if cfg.decision != "mean":
        for name, used, why in (
            ("decision_deadband", cfg.decision_deadband > 0.0, "it holds the ramp's force near the mean's target"),
            ("decision_smoothing", cfg.decision_smoothing < 1.0, "it lags the mean's target"),
            ("decision_full_brake_confirm", cfg.decision_full_brake_confirm > 1, "it ramps toward an unconfirmed full brake"),
            ("decision_brake_share", cfg.decision_brake_share < 1.0, "below 1 it reads the outputs as a softmax"),
        ):  # fmt: skip
            if used:
                raise _bad(name, f"{why}: it needs decision 'mean'")


def check_streams(cfg: Config) -> None:
    """The K-stream trainer's sizes. Raises ConfigError."""
    _at_least(cfg, SECTIONS["streams"], 1)


SECTION_CHECKS = {
    "environment": check_environment, "dqn": check_dqn, "network": check_network, "evaluation": check_evaluation,
    "teacher": check_teacher, "auxiliary": check_auxiliary, "decision": check_decision, "streams": check_streams,
}  # fmt: skip


def check_across_sections(cfg: Config) -> None:
    """The checks that read more than one section. Raises ConfigError."""
    if cfg.brake_margin > 0.0 and cfg.teacher != "none":
        raise _bad("brake_margin", "is a Double DQN loss; a teacher run learns the teacher's labels instead")
    if cfg.decision == "mean" and (cfg.teacher == "none" or cfg.action not in RAMP_ACTIONS):
        raise _bad("decision", "'mean' reads the outputs as a teacher's labels over ramp targets: it needs a teacher and action ramp or ramp-fine")
    if cfg.servers != 1 and (needs := single_stream_only(cfg)) is not None:
        raise ConfigError(*needs)


def config_dict(cfg: Config) -> dict[str, Any]:
    """The config as JSON-ready builtins (what ``config.json`` and checkpoints hold)."""
    d = dataclasses.asdict(cfg)
    d["eval_trajectories"] = list(cfg.eval_trajectories)
    d["train_trajectories"] = list(cfg.train_trajectories)
    return d


def config_from(d: dict[str, Any], path: Any) -> Config:
    """A :class:`Config` from :func:`config_dict`'s output; unknown keys are ignored.

    Args:
        d: the dict.
        path: where it came from, for the error.

    Raises:
        InputFileError: a setting out of range.
    """
    names = {f.name for f in dataclasses.fields(Config)}
    known = {k: v for k, v in d.items() if k in names}
    for name in ("eval_trajectories", "train_trajectories", "eco_weights", "train_sun_elevation", "conv_channels"):
        if name in known:
            known[name] = tuple(known[name])
    for name, value in LEGACY_VALUES.items():  # a config saved before the setting existed
        known.setdefault(name, value)
    try:
        return Config(**known)
    except (TypeError, ValueError) as exc:
        raise InputFileError(f"{path}: bad config: {exc}") from None
