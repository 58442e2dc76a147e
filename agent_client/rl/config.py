"""The settings of a training run: a frozen dataclass per section (environment, DQN,
network, evaluation, teacher, auxiliary heads, decision, streams, actor-critic), each
validating its own fields, and :class:`Config`, which joins them and checks what spans
several.

``vacc train`` generates its options from these fields (:mod:`agent_client.rl.cli`),
so the docstrings below are the ``--help`` text and the defaults are the CLI's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, TypeVar

from agent_client.actions import ACTION_TYPES, RAMP_ACTIONS, is_continuous
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

__all__ = [
    "Config", "ConfigError", "SETTINGS", "SECTIONS", "DECISIONS", "RECURRENT", "ACTOR_LEVELS", "TRUNK_TRAINING", "EMERGENCIES", "SCHEDULES", "TEACHERS", "RESUMABLE_CHANGES", "config_dict", "config_from",
    "EnvironmentSettings", "DQNSettings", "NetworkSettings", "EvaluationSettings", "TeacherSettings", "AuxiliarySettings",
    "DecisionSettings", "StreamsSettings", "ActorCriticSettings",
]  # fmt: skip

SCHEDULES = ("parallel", "serial")
DECISIONS = ("argmax", "mean")  # how the network's outputs become the force (agent_client.rl.network.Policy)
RECURRENT = ("none", "gru")  # the trunk over time: none (the frame stack alone) or a GRU (agent_client.rl.network)
ACTOR_LEVELS = ("none", *RAMP_ACTIONS)  # the actor-critic's output: a tanh, or a mean over a ramp type's levels
TRUNK_TRAINING = ("critic", "frozen", "critic-copy")  # who trains the actor-critic's trunk: the critic (DrQ-v2), none, or the critic its own copy
EMERGENCIES = ("closing", "stopping", "graded")  # the brake margin's emergencies: the lead holds its speed, or brakes on to a stop; graded: any brake that suffices

# Settings a resumed run may change: none of them touches the training RNG or the
# learning (evaluations and checkpoints draw nothing from it), so a run resumed with
# other values stays bit-identical to one that never stopped.
RESUMABLE_CHANGES = ("total_steps", "eval_every", "checkpoint_every", "log_every", "keep_evals")

CRASH_REWARD_RANGE = (-10.0, 0.0)  # the floor of the normalised rewards is -1; a crash may cost more, never gain

# What a run saved before a setting existed did: it trained and evaluated that way.
LEGACY_VALUES = {"schedule": "serial", "set_speed": SET_SPEED_RANGE[1], "action": "levels", "teacher": "none", "teacher_brake": 0.0, "eco_weights": (1.0, 0.5, 0.25, 0.0)}


S = TypeVar("S")


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
            (cfg.recurrent != "none", "recurrent", f"--recurrent {cfg.recurrent}", "stores no recurrent states"),
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
class EnvironmentSettings:
    """The reward, scenario, action and training episodes."""

    reward: str = "gap"
    """Table 1 (gap, force); eco: minus energy, jerk; eco-draw: no regen credit."""
    scenario: str = "ice"
    """"ice" (eq. 7 lead trajectories) or "ev" (real traces)."""
    set_speed: float = DEFAULT_SET_SPEED
    """[m/s] cruise set speed."""
    eco_weights: tuple[float, ...] = ECO_WEIGHTS
    """Eco reward's weights: gap, energy, comfort, closing."""
    action: str = "levels"
    """The force: 21 levels, steps, ramp targets, or continuous (DrQ-v2)."""
    train_trajectories: tuple[str, ...] = ("random",)
    """Leads drawn per episode: random, scenarios (repeat to weight)."""
    train_traffic: int = TRAFFIC_PER_LANE
    """Cars per side lane in training."""
    train_sun_elevation: tuple[float, ...] = SUN_ELEVATION
    """[rad] LOW,HIGH of the training sun's height."""
    crash_reward: float | None = None
    """Reward of a collision, in [-10, 0] (unset: the reward's)."""
    episode_seconds: float | None = 60.0
    """[s] episode length (0: all)."""

    def __post_init__(self) -> None:
        check_environment(self)


@dataclass(frozen=True)
class DQNSettings:
    """The Double DQN's schedule, sizes and rates."""

    total_steps: int = 200_000
    """Environment steps to train (0.1 s each)."""
    seed: int = 1
    """Seed of every RNG of the run."""
    schedule: str = "serial"
    """parallel: update on a second thread while acting."""
    learning_rate: float = 1e-4
    """Adam step size."""
    adam_eps: float = 1.5e-4
    """Adam epsilon."""
    buffer_size: int = 100_000
    """Replay size [transitions]."""
    gamma: float = 0.99
    """Discount per 0.1 s step."""
    target_sync_every: int = 2_000
    """Steps between target syncs."""
    batch_size: int = 32
    """Transitions per update."""
    start_e: float = 1.0
    """ε at step 0."""
    end_e: float = 0.05
    """ε after exploration_steps."""
    exploration_steps: int = 60_000
    """Steps of ε's linear fall."""
    learning_starts: int = 5_000
    """Steps before updates start."""
    train_every: int = 4
    """Environment steps per update."""
    max_grad_norm: float = 10.0
    """Gradient norm clip."""
    n_step: int = 1
    """Steps of the n-step return."""
    absorbing_terminal: bool = True
    """A termination's value: r / (1 - γ), not 0."""
    checkpoint_every: int = 10_000
    """Steps between checkpoints."""
    init_from: str | None = None
    """Checkpoint whose weights start the run."""
    torch_threads: int = 2
    """Torch CPU threads (≤ OMP_NUM_THREADS)."""
    cuda: bool = True
    """Use CUDA if available."""
    log_every: int = 500
    """Steps between scalars."""

    def __post_init__(self) -> None:
        check_dqn(self)


@dataclass(frozen=True)
class NetworkSettings:
    """What the network sees and its widths."""

    frame_stack: int = 8
    """Frames per observation."""
    stack_stride: int = 2
    """Steps between stacked frames."""
    preroll: bool = False
    """Start after the camera pre-roll, as vacc drive."""
    speed_scale: float = 30.0
    """[m/s] host speed divisor."""
    conv_channels: tuple[int, ...] = (16, 32, 64)
    """Conv layers' channels."""
    hidden: int = 256
    """Units of the hidden layer."""
    zoom: int = 1
    """Camera window: 1, the paper's (halved); 2, full resolution."""
    recurrent: str = "none"
    """"gru": a GRU over frames."""
    burn_in: int = 8
    """(gru) steps rebuilding a state."""
    sequence_length: int = 16
    """(gru) steps per sequence."""

    def __post_init__(self) -> None:
        check_network(self)


@dataclass(frozen=True)
class EvaluationSettings:
    """The evaluations that pick best.pt."""

    eval_every: int = 25_000
    """Steps between evaluations (0: only at the end)."""
    eval_trajectories: tuple[str, ...] = TEST_TRAJECTORIES
    """Episodes that pick best.pt: test-N, random:SEED, SCENARIO[:SEED]."""
    eval_seconds: float | None = None
    """[s] evaluation length (0: all)."""
    keep_evals: bool = False
    """Keep each evaluation's policy as evals/STEP.pt."""

    def __post_init__(self) -> None:
        check_evaluation(self)


@dataclass(frozen=True)
class TeacherSettings:
    """The teacher (DAgger) run's labels."""

    teacher: str = "none"
    """DAgger's labels: none, policy or an ACC law (agent_client.rl.teachers)."""
    teacher_policy: str | None = None
    """(--teacher policy) the teacher's checkpoint."""
    teacher_brake: float = 3.5
    """[m/s^2] (teacher, ramp) least deceleration labelled full brake."""
    brake_weight: float = 1.0
    """(teacher) weight of full-brake labels."""
    teacher_lag: float = 0.0
    """[s] (teacher) lag of the law's view of the closing speed."""
    teacher_steps: int = 50_000
    """(teacher) steps over which its share of driving falls to 0."""

    def __post_init__(self) -> None:
        check_teacher(self)


@dataclass(frozen=True)
class AuxiliarySettings:
    """The auxiliary heads' and the brake margin's weights."""

    aux_gap: float = 0.0
    """Weight of a gap head (0: off)."""
    aux_closing: float = 0.0
    """Weight of a closing-speed head (0: off)."""
    brake_margin: float = 0.0
    """(DQN) weight of a full-brake-first loss in emergencies."""
    emergency: str = "closing"
    """(brake margin) lead holds speed, stops; graded: enough brake."""

    def __post_init__(self) -> None:
        check_auxiliary(self)


@dataclass(frozen=True)
class DecisionSettings:
    """How the outputs become the force."""

    decision: str = "argmax"
    """mean: the softmax-weighted target (teacher, ramp)."""
    decision_temperature: float = 2.0
    """(mean) softmax temperature."""
    decision_brake_share: float = 1.0
    """(mean) softmax share at which the full brake acts at once."""
    decision_brake_confirm: int = 1
    """(mean) decisions in a row at the share."""
    decision_full_brake_confirm: int = 1
    """(mean) the same at a full-brake argmax."""
    decision_deadband: float = 0.0
    """(mean) hold the force where the target is this close (0: off)."""
    decision_smoothing: float = 1.0
    """(mean) share of the way to the target each step (1: off)."""

    def __post_init__(self) -> None:
        check_decision(self)


@dataclass(frozen=True)
class StreamsSettings:
    """The K-stream trainer's sizes."""

    servers: int = 1
    """Servers feeding one learner."""
    weight_sync_every: int = 20
    """(servers > 1) updates between weight syncs."""
    actor_batch: int = 50
    """(servers > 1) transitions per delivery."""

    def __post_init__(self) -> None:
        check_streams(self)


@dataclass(frozen=True)
class ActorCriticSettings:
    """DrQ-v2's noise, target rate, augmentation and warm start."""

    noise_start: float = 1.0
    """(continuous) noise std at step 0."""
    noise_end: float = 0.1
    """(continuous) that std after exploration_steps."""
    noise_clip: float = 0.3
    """(continuous) clip of the target policy's smoothing noise."""
    critic_tau: float = 0.01
    """(continuous) Polyak rate of the critic's target."""
    shift_pad: int = 4
    """(continuous) [px] largest random image shift (0: none)."""
    bc_steps: int = 0
    """(continuous) steps cloning --init-from into the actor."""
    critic_warmup: int = 0
    """(continuous) first updates in which only the critic learns."""
    bc_weight: float = 0.0
    """(continuous) TD3+BC pull toward init_from's decision."""
    actor_levels: str = "none"
    """(continuous) tanh, or a ramp's softmax mean."""
    trunk_training: str = "critic"
    """(continuous) who trains the actor's trunk."""

    def __post_init__(self) -> None:
        check_actor_critic(self)


@dataclass(frozen=True)
class Config(ActorCriticSettings, StreamsSettings, DecisionSettings, AuxiliarySettings, TeacherSettings,
             EvaluationSettings, NetworkSettings, DQNSettings, EnvironmentSettings):
    """Every setting of a training run: the sections above, in one flat namespace (the
    CLI's options, ``config.json`` and the recipes name fields, not sections). The CLI
    only fills this in."""

    def __post_init__(self) -> None:
        # Each section's own check, once: a section must not call super().__post_init__(),
        # or Config's multiple inheritance would run the others' checks again.
        for kind in SETTINGS.values():
            kind.__post_init__(self)  # type: ignore[attr-defined]
        check_across_sections(self)

    def section(self, kind: type[S]) -> S:
        """The settings of one section (``cfg.section(DQNSettings)``), as their own object."""
        return kind(**{f.name: getattr(self, f.name) for f in dataclasses.fields(kind)})  # type: ignore[arg-type]

    @property
    def stores_gaps(self) -> bool:
        """Whether the replay keeps each observation's gap: the privileged target of the
        auxiliary heads and the brake margin's emergencies, never an input."""
        return self.aux_gap > 0.0 or self.aux_closing > 0.0 or self.brake_margin > 0.0

    @property
    def stores_lead_stops(self) -> bool:
        """Whether the replay keeps the distance the lead needs to stop at its present
        deceleration (privileged, never an input): the brake margin's ``stopping`` emergencies."""
        return self.brake_margin > 0.0 and self.emergency != "closing"


# The sections, by name; each validates itself, and check_across_sections reads several.
SETTINGS: dict[str, type] = {
    "environment": EnvironmentSettings, "dqn": DQNSettings, "network": NetworkSettings, "evaluation": EvaluationSettings,
    "teacher": TeacherSettings, "auxiliary": AuxiliarySettings, "decision": DecisionSettings, "streams": StreamsSettings,
    "actor_critic": ActorCriticSettings,
}  # fmt: skip
SECTIONS: dict[str, tuple[str, ...]] = {name: tuple(f.name for f in dataclasses.fields(kind)) for name, kind in SETTINGS.items()}


def _bad(name: str, message: str) -> ConfigError:
    return ConfigError(name, f"{name} {message}")


def _at_least(cfg: Any, names: tuple[str, ...], low: int) -> None:
    """Raises ConfigError: the first of ``names`` below ``low``."""
    for name in names:
        if getattr(cfg, name) < low:
            raise _bad(name, f"must be >= {low}")


def _finite_and_not_negative(cfg: Any, names: tuple[str, ...]) -> None:
    """Raises ConfigError: the first of ``names`` that is not finite and >= 0."""
    for name in names:
        if not (math.isfinite(getattr(cfg, name)) and getattr(cfg, name) >= 0.0):
            raise _bad(name, f"must be finite and >= 0, got {getattr(cfg, name)}")


def check_environment(cfg: EnvironmentSettings) -> None:
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


def check_dqn(cfg: DQNSettings) -> None:
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


def check_network(cfg: NetworkSettings) -> None:
    """What the network sees and its widths. Raises ConfigError."""
    if len(cfg.conv_channels) != 3 or not all(isinstance(c, int) and 1 <= c <= 512 for c in cfg.conv_channels):
        raise _bad("conv_channels", f"must be three whole numbers in 1..512, got {','.join(map(str, cfg.conv_channels))}")
    if not 1 <= cfg.hidden <= 4096:
        raise _bad("hidden", f"must be in 1..4096, got {cfg.hidden}")
    _at_least(cfg, ("frame_stack", "stack_stride"), 1)
    if cfg.zoom not in ZOOMS:
        raise _bad("zoom", f"must be one of {ZOOMS}")
    if cfg.recurrent not in RECURRENT:
        raise _bad("recurrent", f"must be one of {RECURRENT}, got {cfg.recurrent!r}")
    _at_least(cfg, ("burn_in",), 0)
    if not cfg.burn_in < cfg.sequence_length:
        raise _bad("sequence_length", f"must be longer than burn_in ({cfg.burn_in}) so that a sequence trains a step, got {cfg.sequence_length}")


def check_evaluation(cfg: EvaluationSettings) -> None:
    """The evaluations that pick best.pt. Raises ConfigError."""
    _at_least(cfg, ("eval_every",), 0)
    for name in cfg.eval_trajectories:
        try:
            eval_episode(name)  # a typo fails here, not at the first evaluation hours later
        except ValueError as exc:
            raise ConfigError("eval_trajectories", str(exc)) from None


def check_teacher(cfg: TeacherSettings) -> None:
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


def check_auxiliary(cfg: AuxiliarySettings) -> None:
    """The auxiliary heads' and the brake margin's weights. Raises ConfigError."""
    _finite_and_not_negative(cfg, tuple(n for n in SECTIONS["auxiliary"] if n != "emergency"))
    if cfg.emergency not in EMERGENCIES:
        raise _bad("emergency", f"must be one of {', '.join(EMERGENCIES)}, got {cfg.emergency!r}")
    if cfg.emergency != "closing" and cfg.brake_margin == 0.0:
        raise _bad("emergency", "says what the brake margin counts as an emergency: give brake_margin > 0")


def check_decision(cfg: DecisionSettings) -> None:
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


def check_streams(cfg: StreamsSettings) -> None:
    """The K-stream trainer's sizes. Raises ConfigError."""
    _at_least(cfg, SECTIONS["streams"], 1)


def check_actor_critic(cfg: ActorCriticSettings) -> None:
    """DrQ-v2's noise, target rate, augmentation and warm start. Raises ConfigError."""
    _finite_and_not_negative(cfg, ("noise_start", "noise_end", "noise_clip", "bc_weight"))
    if not 0.0 < cfg.critic_tau <= 1.0:
        raise _bad("critic_tau", f"must be in (0, 1], got {cfg.critic_tau}")
    if not 0 <= cfg.shift_pad <= 16:
        raise _bad("shift_pad", f"must be in 0..16 px, got {cfg.shift_pad}")
    _at_least(cfg, ("bc_steps", "critic_warmup"), 0)
    if cfg.actor_levels not in ACTOR_LEVELS:
        raise _bad("actor_levels", f"must be one of {', '.join(ACTOR_LEVELS)}, got {cfg.actor_levels!r}")
    if cfg.trunk_training not in TRUNK_TRAINING:
        raise _bad("trunk_training", f"must be one of {', '.join(TRUNK_TRAINING)}, got {cfg.trunk_training!r}")


def check_across_sections(cfg: Config) -> None:
    """The checks that read more than one section. Raises ConfigError."""
    if cfg.brake_margin > 0.0 and cfg.teacher != "none":
        raise _bad("brake_margin", "is a Double DQN loss; a teacher run learns the teacher's labels instead")
    if cfg.emergency == "graded" and cfg.action != "levels":
        raise _bad("emergency", f"'graded' reads the outputs as the 21 force levels: it needs action 'levels', got {cfg.action!r}")
    if cfg.decision == "mean" and (cfg.teacher == "none" or cfg.action not in RAMP_ACTIONS):
        raise _bad("decision", "'mean' reads the outputs as a teacher's labels over ramp targets: it needs a teacher and action ramp or ramp-fine")
    if cfg.servers != 1 and (needs := single_stream_only(cfg)) is not None:
        raise ConfigError(*needs)
    check_continuous(cfg)
    check_recurrent(cfg)


def check_recurrent(cfg: Config) -> None:
    """What the recurrent trunk does not do yet. Raises ConfigError."""
    if cfg.recurrent == "none":
        return
    for field, used, what in (
        ("n_step", cfg.n_step != 1, "n-step returns (one-step targets from the unrolled sequence)"),
        ("brake_margin", cfg.brake_margin > 0.0, "a brake margin"),
        ("teacher", cfg.teacher == "policy", "a policy teacher (a law's labels only)"),
        ("trunk_training", cfg.trunk_training == "critic-copy", "copy of its trunk for the critic"),
    ):  # fmt: skip
        if used:
            raise _bad(field, f"is not for the recurrent trunk (recurrent {cfg.recurrent!r}): it has no {what}")


def check_continuous(cfg: Config) -> None:
    """What the actor-critic (``action`` "continuous") does not do, and what only it does.
    Raises ConfigError."""
    if not is_continuous(cfg.action):
        if cfg.bc_steps > 0:
            raise _bad("bc_steps", "clones a DQN into the actor-critic's actor: it needs action 'continuous'")
        if cfg.critic_warmup > 0:
            raise _bad("critic_warmup", "holds the actor-critic's actor while its critic learns: it needs action 'continuous'")
        if cfg.actor_levels != "none":
            raise _bad("actor_levels", "is the actor-critic's output: it needs action 'continuous'")
        if cfg.bc_weight > 0.0:
            raise _bad("bc_weight", "anchors the actor-critic's actor to a student: it needs action 'continuous'")
        if cfg.trunk_training != "critic":
            raise _bad("trunk_training", "says who trains the actor-critic's trunk: it needs action 'continuous'")
        return
    for field, used, what in (
        ("teacher", cfg.teacher != "none", "a teacher's labels (clone a student with init_from and bc_steps)"),
        ("aux_gap", cfg.aux_gap > 0.0, "auxiliary heads"), ("aux_closing", cfg.aux_closing > 0.0, "auxiliary heads"),
        ("brake_margin", cfg.brake_margin > 0.0, "a brake margin"), ("decision", cfg.decision != "argmax", "another decision rule"),
    ):  # fmt: skip
        if used:
            raise _bad(field, f"is not for the actor-critic (action 'continuous'): it has no {what}")
    for field in ("bc_steps", "bc_weight"):
        if getattr(cfg, field) > 0 and cfg.init_from is None:
            raise _bad(field, "reads the init_from checkpoint's decision: give init_from")
    if cfg.trunk_training != "critic" and cfg.init_from is None:
        raise _bad("trunk_training", f"{cfg.trunk_training!r} keeps the trunk init_from gives: give init_from")


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
