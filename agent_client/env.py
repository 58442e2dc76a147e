"""Gymnasium environment over a real UDP session with the simulator server.

Registered as ``vacc/VisionACC-v0`` when this module is imported. Gymnasium 1.x
has no plugin entry points, so after ``pip install`` alone name the module in the
id, and ``gym.make`` imports it::

    env = gym.make("agent_client.env:vacc/VisionACC-v0")
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from agent_client import preprocess as pre
from agent_client.actions import ACTION_TYPES, is_continuous, make_action_type
from agent_client.errors import FatalSessionError
from agent_client.launcher import local_server
from agent_client.rewards import (
    CONTROL_PERIOD,
    ECO_WEIGHTS,
    REWARDS,
    make_reward,
    make_reward_terms,
)
from agent_client.session import GIVE_UP, Session
from agent_client.stacker import MAX_SPEED, FrameStacker
from protocol.auth import load_key
from protocol.constants import CAMERA_SIZE, FORCES, N_ACTIONS
from protocol.scenarios import (
    LEAD_SCENARIOS,
    RANDOM_DURATION,
    TEST_DURATION,
    check_initial,
    check_trajectory,
)

__all__ = ["VisionACCEnv", "FORCES", "N_ACTIONS", "MAX_SPEED", "ENV_ID", "MAX_EPISODE_STEPS"]

ENV_ID = "vacc/VisionACC-v0"
log = logging.getLogger("vacc.env")
RESET_OPTIONS = frozenset({"seed", "trajectory", "host_speed", "gap", "set_speed"})
# The longest named trajectory (the 240 s tests and random episodes) in control steps:
# gym.make's TimeLimit, a backstop the server's own truncation reaches at the same step.
MAX_EPISODE_STEPS = round(max(TEST_DURATION, RANDOM_DURATION, *(s.duration for s in LEAD_SCENARIOS.values())) / CONTROL_PERIOD)


def _action_space(action: str, n: int) -> spaces.Space[Any]:
    """``Box(-1, 1, (n,))`` for a continuous action type (its target force), else ``Discrete(n)``."""
    return spaces.Box(-1.0, 1.0, (n,), np.float32) if is_continuous(action) else spaces.Discrete(n)


class VisionACCEnv(gym.Env):
    """Follow a lead car from a front camera, over a UDP lockstep session.

    ## Action space
    ``action="levels"`` (the paper): ``Discrete(21)``, action ``a`` applies the
    normalised force ``u = -1 + 0.1 a`` for one control period (0.1 s by default);
    u = -1 brakes at 5.5 m/s², u = +1 accelerates at 3.5 m/s².
    ``action="steps"``: ``Discrete(6)``, action ``a`` adds
    :data:`agent_client.actions.FORCE_STEPS` ``[a]`` to the force held since the last
    step (0 at the start), so the policy cannot jerk by accident.
    ``action="ramp"``: ``Discrete(21)``, action ``a`` picks the level ``-1 + 0.1 a`` as
    the target of a held force that moves toward it by at most
    :data:`agent_client.actions.RAMP_RATE` per step; the full brake acts at once.
    ``action="ramp-fine"``: the same with :data:`agent_client.actions.FINE_LEVELS` as
    the 21 targets, dense near zero.
    ``action="continuous"``: ``Box(-1, 1, (1,), float32)``, the target force itself; the
    held force ramps toward it as ``"ramp"``'s does, and a target at or below
    :data:`agent_client.actions.FULL_BRAKE_TARGET` (-0.95) is the full brake, at once.

    ## Observation space
    ``Dict(frames=Box(0, 255, (8, 105, 150), uint8), speeds=Box(0, 60, (8,), float32))``:
    the last 8 preprocessed camera frames (oldest first, ``stack_stride`` control
    steps apart) and the host speeds [m/s] at those frames. With a held-force action (``"steps"``, ``"ramp"``, ``"ramp-fine"``, ``"continuous"``),
    also ``controls=Box((8, 2), float32)``: at each stacked frame the force then held
    (the agent's own last output) and the cruise set speed [m/s] (the driver's input).
    The gap, the lead's speed and every other privileged quantity are never in the
    observation; they are in ``info`` for logging and feed only the reward.

    ## Rewards
    Table 1 of the paper (:mod:`agent_client.rewards`): ``reward="gap"`` or
    ``"force"``, normalised to [-1, 1]; or ``"eco"``: the gap term minus the host's
    instantaneous energy, its jerk and its speed difference to the lead, weighted by
    ``eco_weights`` (beyond the paper). ``crash_reward``: a collision step's reward
    instead of the reward's own value at contact (None: unchanged; see
    :attr:`agent_client.rl.config.Config.crash_reward`).
    Each step's ``info["reward_terms"]`` holds the reward by term (below).

    ## Info
    ``reset`` and ``step`` both return, from the server's observation: ``t`` [s],
    ``frame``, ``gap`` [m], ``v_host``, ``v_lead`` [m/s], ``a_lead``, ``accel``
    [m/s²] (over the last control period), ``force`` (the u applied), ``collision``,
    ``reason`` ("", "collision", "gap" or "end") and ``set_speed`` [m/s]. ``reset``
    adds ``seed`` (the episode seed drawn or given) and, with ``preroll``, ``preroll``.
    ``step`` adds ``reward_terms``: a dict of the reward's terms by name, *weighted*
    (each already times its weight and over the reward's normaliser), so that their
    sum is the returned reward to float rounding (the reward itself is computed
    whole, as ever): ``gap`` reward: ``gap``; ``force``: ``gap``, ``force``;
    ``eco``: ``gap``, ``energy``, ``comfort``, ``closing`` (the last three signed as
    paid: <= 0 but for an EV's regeneration). Every reward also has ``crash``: 0.0,
    but on a collision step with ``crash_reward`` set, where it is ``crash_reward``
    and the reward's own terms are 0.0 (the value replaced them). Like the gap, these
    are privileged: logging and reward studies only
    (:func:`agent_client.rewards.make_reward_terms`).

    ## Starting state
    Table 2 of the paper for the scenario (or the lead scenario's own ranges,
    ``docs/scenarios.md``): initial host speed and gap drawn from the episode seed;
    the lead follows the chosen trajectory. ``reset(options=...)`` may set
    ``trajectory``, ``seed``, ``host_speed`` [m/s], ``gap`` [m] and ``set_speed``
    [m/s] for one episode.

    ## Set speed
    The host never drives faster than the cruise set speed (default 33.5 m/s; the
    simulator's speed limiter). It is a driver input, not privileged: ``info``
    carries it as ``set_speed``.

    ## Episode end
    Terminated on a collision or a gap over 300 m; truncated at the end of the
    trajectory (240 s) or ``episode_seconds``. ``gym.make`` adds a ``TimeLimit`` of
    :data:`MAX_EPISODE_STEPS` (2400: 240 s at 0.1 s); pass ``max_episode_steps=`` if
    ``server_args`` change the control period (``--substeps``).

    ## Rendering
    ``render_mode="rgb_array"``: ``render()`` returns the camera frame the agent's
    observation was cut from, in colour: ``(200, 200, 3)`` uint8 at ``zoom=1``,
    ``(400, 400, 3)`` at ``zoom=2``. The session then asks for RGB frames and the env
    converts them to gray as the server would (the same ``cv2`` conversion), so the
    observation is bit-identical to an unrendered env's. ``render_mode="human"``:
    the same frame in a pygame window (``pip install 'vacc[human]'``), drawn on
    every ``reset`` and ``step`` at ``render_fps`` (real time); without a display
    (``DISPLAY``, ``WAYLAND_DISPLAY`` or an explicit ``SDL_VIDEODRIVER``) it warns
    and draws offscreen. ``gymnasium.wrappers.RecordVideo`` works with
    ``rgb_array``.

    ## Making it
    ``gym.make("agent_client.env:vacc/VisionACC-v0", scenario="ice")`` works after
    ``pip install`` alone (the ``module:`` prefix imports the module that registers
    the id; Gymnasium 1.x has no plugin entry points). After ``import
    agent_client.env``, ``gym.make("vacc/VisionACC-v0")`` works as well.

    ## Arguments
    ``server``: (host, port) of a running server, or None to spawn one (reaped on
    ``close``). ``scenario``: "ice" | "ev". ``trajectory``: "random" (a new one each
    episode), "test-1".."test-4" or a lead scenario (``stopped``, ``brake-stop``, ...;
    :data:`protocol.scenarios.TRAJECTORIES`). ``set_speed``: cruise set speed [m/s],
    None for the default. ``frame_stack``, ``stack_stride``: the stack.
    ``preroll``: start each episode after the camera pre-roll the stack spans, the host
    coasting meanwhile (protocol 4, docs/scenarios.md), so the first observation stacks
    real frames; its ``info["preroll"]`` holds those frames' newest entries. False: the
    first frame repeated.
    ``zoom``: 1, the paper's preprocessing (a 200x200 gray camera, the 400x400 one
    halved); 2, the same 105x150 window at full resolution (a 400x400 gray camera;
    :mod:`agent_client.preprocess`).
    ``seat``: a platoon server's seat to drive (:mod:`agent_client.platoon_env` drives
    every seat at once); None: the first free one.

    ## Version history
    * v0: first version; lead scenarios, ``set_speed`` and the ``host_speed``/``gap``
      reset options added with protocol version 2; ``action="steps"``; colour
      ``rgb_array``, ``human`` rendering and ``max_episode_steps`` (no change to
      observations, rewards or dynamics, so still v0); ``preroll`` (off by default);
      ``info["reward_terms"]`` (the reward's value unchanged, so still v0);
      ``action="continuous"`` (a new action type; the others unchanged, so still v0).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": round(1.0 / CONTROL_PERIOD)}

    def __init__(
        self,
        server: tuple[str, int] | None = None,
        *,
        scenario: str = "ice",
        trajectory: str = "random",
        reward: str = "gap",
        frame_stack: int = 8,
        stack_stride: int = 1,
        episode_seconds: float | None = None,
        render_mode: str | None = None,
        give_up: float = GIVE_UP,
        server_args: tuple[str, ...] = (),
        zoom: int = 1,
        set_speed: float | None = None,
        key_file: str | None = None,
        action: str = "levels",
        eco_weights: tuple[float, ...] = ECO_WEIGHTS,
        preroll: bool = False,
        crash_reward: float | None = None,
        seat: int | None = None,
    ):
        if crash_reward is not None and not np.isfinite(crash_reward):
            raise ValueError(f"crash_reward must be finite, got {crash_reward}")
        if action not in ACTION_TYPES:
            raise ValueError(f"action {action!r} is not one of {ACTION_TYPES}")
        check_trajectory(trajectory)
        check_initial(host_speed=None, gap=None, set_speed=set_speed)
        if reward not in REWARDS:
            raise ValueError(f"reward {reward!r} is not one of {sorted(REWARDS)}")
        if frame_stack < 1 or stack_stride < 1:
            raise ValueError("frame_stack and stack_stride must be >= 1")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} is not one of {self.metadata['render_modes']}")
        if render_mode == "human":  # fail before a server is spawned, not at the first draw
            from agent_client.controllers.keyboard import has_display, require_pygame

            require_pygame()
            if not has_display():  # the agent drives, so no error; and no warning: check_env tries every mode headless
                log.info("render_mode='human' without a display (DISPLAY, WAYLAND_DISPLAY): the window is drawn offscreen, unseen")
        image_size = pre.camera_size(zoom)  # checks zoom
        self.preroll = (frame_stack - 1) * stack_stride if preroll else 0
        self.zoom = zoom
        self.scenario, self.trajectory = scenario, trajectory
        self.set_speed = set_speed
        self.reward_fn = make_reward(reward, scenario, eco_weights)
        self.reward_terms_fn = make_reward_terms(reward, scenario, eco_weights)
        self.crash_reward = crash_reward
        self._a_prev = 0.0  # [m/s^2] the host's acceleration over the previous step
        self.frame_stack, self.stack_stride = frame_stack, stack_stride
        self.episode_seconds = episode_seconds
        self.render_mode = render_mode
        self.actions = make_action_type(action)
        self.action_space = _action_space(action, self.actions.n)
        observed: dict[str, spaces.Space[Any]] = {
            "frames": spaces.Box(0, 255, (frame_stack, pre.FRAME_H, pre.FRAME_W), np.uint8),
            "speeds": spaces.Box(0.0, MAX_SPEED, (frame_stack,), np.float32),
        }
        if self.actions.n_controls:
            observed["controls"] = spaces.Box(-np.inf, np.inf, (frame_stack, self.actions.n_controls), np.float32)
        self.observation_space = spaces.Dict(observed)
        self._stack = contextlib.ExitStack()
        # key_file: the shared key of a remote server (vacc serve --key-file); a spawned one gets it too.
        key = load_key(key_file) if key_file is not None else None
        addr = server if server is not None else self._stack.enter_context(local_server(*server_args, key_file=key_file))
        # Rendering asks for the same camera in colour; preprocess converts it to gray
        # exactly as the server would, so the observation does not change.
        image_format = "gray" if render_mode is None else "rgb"
        self.session = self._stack.enter_context(
            Session(addr, image_format=image_format, image_size=image_size, give_up=give_up, client_name="vacc-env", key=key, seat=seat)
        )
        self._stacker = FrameStacker(frame_stack, stack_stride)
        self._last_image: np.ndarray | None = None
        self._last_info: dict[str, Any] = {}
        self._window: Any = None  # the human render mode's DrivingWindow, opened on first draw
        self._clock: Any = None

    def _observe(self, obs: dict[str, Any]) -> dict[str, np.ndarray]:
        image = Session.image(obs)
        if image is None:  # the session asked for frames; a server that drops them is broken
            raise FatalSessionError("the server sent an observation without a camera image")
        self._last_image = image
        self.actions.observe(float(obs["accel"]))  # anti-windup of a held force
        controls = self.actions.controls(float(obs["set_speed"])) if self.actions.n_controls else None
        return self._stacker.push(pre.preprocess(image, self.zoom), obs["v_host"], controls)

    @staticmethod
    def _info(obs: dict[str, Any]) -> dict[str, Any]:
        keys = ("t", "frame", "gap", "v_host", "v_lead", "a_lead", "accel", "force", "collision", "reason", "set_speed")
        return {k: obs[k] for k in keys}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        episode_seed = int(options.get("seed", self.np_random.integers(2**31)))
        unknown = set(options) - RESET_OPTIONS
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; expected some of {sorted(RESET_OPTIONS)}")
        trajectory = check_trajectory(options.get("trajectory", self.trajectory))
        set_speed = options.get("set_speed", self.set_speed)
        host_speed, gap = options.get("host_speed"), options.get("gap")
        check_initial(host_speed=host_speed, gap=gap, set_speed=set_speed)
        obs = self.session.reset(
            scenario=self.scenario,
            seed=episode_seed,
            trajectory=trajectory,
            duration=self.episode_seconds,
            host_speed=host_speed,
            gap=gap,
            set_speed=set_speed,
            preroll=self.preroll,
        )
        self._stacker.reset()
        self.actions.reset()
        history = []
        while obs["frame"] < 0:  # the pre-roll: stacked, not acted on (the server ignores the action)
            stacked = self._observe(obs)
            history.append({k: v[-1:] for k, v in stacked.items()})
            obs = self.session.step(0.0)
        self._a_prev = float(obs.get("accel", 0.0))
        info = self._info(obs)
        info["seed"] = episode_seed
        if self.preroll:
            info["preroll"] = history  # each frame's newest entries, for a replay memory (ReplayMemory.warm)
        observation = self._observe(obs)
        self._after(info)
        return observation, info

    def step(self, action):
        if isinstance(self.action_space, spaces.Box):
            target = np.asarray(action, np.float32).reshape(-1)  # a float or a [1] array
            if target.shape != (1,) or not self.action_space.contains(target):
                raise ValueError(f"action {action!r} is not in {self.action_space}")
            return self._advance(self.actions.force(float(target[0])))
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in {self.action_space}")
        return self._advance(self.actions.force(int(action)))

    def step_toward(self, target: float):
        """:meth:`step` with a ramp toward a force between the target levels instead of an
        action (the mean decision, :class:`agent_client.rl.network.Policy`); the same returns.

        Raises:
            ValueError: an action type without a ramp.
        """
        force_toward = getattr(self.actions, "force_toward", None)
        if force_toward is None:
            raise ValueError(f"action type {self.actions.name!r} has no ramp to move toward a target")
        return self._advance(force_toward(float(target)))

    def _advance(self, u: float):
        """Apply the force ``u`` for one control step; the Gymnasium step's returns."""
        obs = self.session.step(u)
        a = float(obs["accel"])
        kw = {"v": float(obs["v_host"]), "a": a, "a_prev": self._a_prev, "v_lead": float(obs["v_lead"])}
        reward = self.reward_fn(obs["gap"], u, **kw)
        terms = self.reward_terms_fn(obs["gap"], u, **kw)
        crash = 0.0
        if obs["collision"] and self.crash_reward is not None:
            reward = crash = self.crash_reward
            terms = dict.fromkeys(terms, 0.0)  # the crash value replaces the reward's own
        terms["crash"] = crash
        self._a_prev = a
        observation, info = self._observe(obs), self._info(obs)
        info["reward_terms"] = terms
        self._after(info)
        return observation, reward, bool(obs["terminated"]), bool(obs["truncated"]), info

    def _after(self, info: dict[str, Any]) -> None:
        self._last_info = info
        if self.render_mode == "human":  # Gymnasium's convention: human mode draws itself
            self.render()

    def render(self) -> np.ndarray | None:
        """The last camera frame in colour (``rgb_array``), or draw it (``human``).

        Returns:
            ``(H, W, 3)`` uint8 for ``rgb_array``; None for ``human``, without a
            render mode, or before the first ``reset``.

        Raises:
            agent_client.controllers.keyboard.PygameMissing: ``human`` without pygame.
            agent_client.controllers.keyboard.NoDisplay: ``human`` without a display.
        """
        if self._last_image is None:
            return None
        if self.render_mode == "rgb_array":
            return self._last_image.copy()  # the caller may keep it; the next step reuses nothing
        if self.render_mode == "human":
            self._draw(self._last_image)
        return None

    def _draw(self, image: np.ndarray) -> None:
        if self._window is None:
            # pygame only when asked for
            from agent_client.controllers.keyboard import DrivingWindow

            scale = max(1, CAMERA_SIZE[0] // image.shape[1])
            self._window = DrivingWindow(scale, f"{ENV_ID} ({self.scenario}/{self.trajectory})", offscreen_ok=True)
            self._stack.callback(self._window.close)
            self._clock = self._window.pg.time.Clock()
        self._window.events()  # keeps the window responsive; the agent, not the keys, drives
        i = self._last_info
        lines = [
            f"t {i['t']:6.1f} s   speed {i['v_host']:5.2f} m/s   set {i['set_speed']:5.2f} m/s",
            f"gap {i['gap']:6.1f} m   lead {i['v_lead']:5.2f} m/s   force {i['force']:+.2f}",
        ]
        self._window.draw(image, lines)
        self._clock.tick(self.metadata["render_fps"])

    def close(self) -> None:
        self._stack.close()


gym.register(id=ENV_ID, entry_point="agent_client.env:VisionACCEnv", max_episode_steps=MAX_EPISODE_STEPS)
