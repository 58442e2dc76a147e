"""Stable-Baselines3 peers for `vacc bench`: DQN and SAC training steps/s, replay bytes and
the decision latency.

SB3's DQN runs on our own Gymnasium env (the real UDP path), with a features
extractor of exactly our network's size, so the two learners differ only in their
training loops and replay memories.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

INSTALL_HINT = "stable-baselines3 is not installed: pip install 'vacc[bench]' (make bench does)"


def _extractor_class() -> Any:
    import torch
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    from agent_client.rl.network import QNetwork

    class VaccExtractor(BaseFeaturesExtractor):
        """Our QNetwork minus its last layer; SB3 adds the 256 -> 21 head (or SAC's actor and
        critics). With controls in the observation (the continuous action), they join as ours do."""

        def __init__(self, observation_space: Any, frame_stack: int = 8):
            super().__init__(observation_space, features_dim=256)
            n_controls = observation_space["controls"].shape[1] if "controls" in observation_space.spaces else 0
            q = QNetwork(frame_stack, n_controls=n_controls)
            self.conv, self.fc = q.conv, q.fc[:2]
            self.speed_scale = q.speed_scale
            self.control_scale = torch.tensor([1.0, q.speed_scale][:n_controls])

        def forward(self, obs: dict[str, Any]) -> Any:
            # SB3 has already scaled the uint8 frames to [0, 1].
            parts = [self.conv(obs["frames"]), obs["speeds"] / self.speed_scale]
            if "controls" in obs:
                parts.append((obs["controls"] / self.control_scale).flatten(1))
            return self.fc(torch.cat(parts, dim=1))

    return VaccExtractor


def _timed_learn(model: Any, steps: int) -> float:
    """Wall time [s] of ``model.learn`` over ``steps`` environment steps."""
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps)
    return time.perf_counter() - t0


def sb3_training_rate(steps: int, learning_starts: int, train_every: int = 8, threads: int = 2) -> dict[str, Any]:
    """SB3 DQN (MultiInputPolicy, our net size) training steps/s against a real server.

    Run it in a process of its own (:func:`sb3_training_rate_isolated`): vacc's learner
    tunes the process's allocator, which would speed SB3 up too.
    """
    try:
        import torch
        from stable_baselines3 import DQN
    except ImportError:
        return {"error": INSTALL_HINT}
    from agent_client.env import VisionACCEnv

    torch.set_num_threads(threads)  # as many as vacc's learner uses
    env = VisionACCEnv(trajectory="random", stack_stride=2, episode_seconds=60.0)
    try:
        model = DQN(
            "MultiInputPolicy", env, buffer_size=max(steps, 1000), learning_starts=learning_starts,
            batch_size=32, train_freq=train_every, gradient_steps=1, target_update_interval=2000,
            policy_kwargs={"features_extractor_class": _extractor_class(), "net_arch": []},
            seed=1, device="cpu", verbose=0,
        )  # fmt: skip
        wall = _timed_learn(model, steps)
    finally:
        env.close()
    return {"steps": steps, "wall_s": wall, "steps_per_s_overall": steps / wall, "train_every": train_every, "threads": threads}


def sb3_sac_training_rate(steps: int, learning_starts: int, train_every: int = 8, threads: int = 2) -> dict[str, Any]:
    """SB3 SAC (MultiInputPolicy, our trunk's size shared by its actor and critics) training
    steps/s on the continuous action against a real server: the actor-critic's peer.

    Run it in a process of its own (:func:`sb3_training_rate_isolated` with ``algo="sac"``).
    """
    try:
        import torch
        from stable_baselines3 import SAC
    except ImportError:
        return {"error": INSTALL_HINT}
    from agent_client.env import VisionACCEnv

    torch.set_num_threads(threads)
    env = VisionACCEnv(trajectory="random", stack_stride=2, episode_seconds=60.0, action="continuous")
    try:
        model = SAC(
            "MultiInputPolicy", env, buffer_size=max(steps, 1000), learning_starts=learning_starts, batch_size=32,
            train_freq=train_every, gradient_steps=1,
            policy_kwargs={"features_extractor_class": _extractor_class(), "net_arch": [256], "share_features_extractor": True},
            seed=1, device="cpu", verbose=0,
        )  # fmt: skip
        wall = _timed_learn(model, steps)
    finally:
        env.close()
    return {"steps": steps, "wall_s": wall, "steps_per_s_overall": steps / wall, "train_every": train_every, "threads": threads}


def sb3_training_rate_isolated(steps: int, learning_starts: int, train_every: int = 8, threads: int = 2, algo: str = "dqn") -> dict[str, Any]:
    """:func:`sb3_training_rate` (``algo`` "dqn") or :func:`sb3_sac_training_rate` ("sac") in a
    fresh Python process, as a user would run SB3."""
    import json
    import subprocess
    import sys

    name = {"dqn": "sb3_training_rate", "sac": "sb3_sac_training_rate"}[algo]
    code = f"import json; from vacc.bench_sb3 import {name}; print(json.dumps({name}({steps}, {learning_starts}, {train_every}, {threads})))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["SB3 peer failed"])[-1]}
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]))


def sb3_decision_latency(repeats: int = 300) -> dict[str, Any]:
    """Median and p90 [s] of SB3's ``policy.predict`` (deterministic, batch 1, one thread) for a
    stacked observation, with a Q-network of our size: SB3's own inference path beside ours.

    It is handed the stack ready-made (eight 105x150 uint8 frames and eight speeds), so it
    does less than our decision, which also crops and stacks the received frame.
    """
    try:
        from stable_baselines3.dqn.policies import MultiInputPolicy
    except ImportError:
        return {"error": INSTALL_HINT}
    from agent_client.bench.ddqn import latency, one_torch_thread

    obs_space, action_space = _spaces()
    with one_torch_thread():
        policy = MultiInputPolicy(obs_space, action_space, lambda _: 1e-4, net_arch=[], features_extractor_class=_extractor_class())
        policy.set_training_mode(False)
        rng = np.random.default_rng(0)
        obs: dict[str, np.ndarray] = {"frames": rng.integers(0, 256, obs_space["frames"].shape, dtype=np.uint8), "speeds": np.full(8, 30.0, np.float32)}
        return latency(lambda: policy.predict(obs, deterministic=True), repeats)


def sb3_sac_decision_latency(repeats: int = 300) -> dict[str, Any]:
    """Median and p90 [s] of SB3 SAC's ``policy.predict`` (deterministic, batch 1, one thread)
    for a stacked observation with controls, its trunk of our size: the actor's peer."""
    try:
        from stable_baselines3.sac.policies import MultiInputPolicy
    except ImportError:
        return {"error": INSTALL_HINT}
    from gymnasium import spaces

    from agent_client.bench.ddqn import latency, one_torch_thread

    obs_space, _ = _spaces()
    obs_space = spaces.Dict({**obs_space.spaces, "controls": spaces.Box(-np.inf, np.inf, (8, 2), np.float32)})
    with one_torch_thread():
        policy = MultiInputPolicy(obs_space, spaces.Box(-1.0, 1.0, (1,), np.float32), lambda _: 1e-4, net_arch=[256],
                                  features_extractor_class=_extractor_class(), share_features_extractor=True)  # fmt: skip
        policy.set_training_mode(False)
        rng = np.random.default_rng(0)
        obs: dict[str, np.ndarray] = {"frames": rng.integers(0, 256, obs_space["frames"].shape, dtype=np.uint8), "speeds": np.full(8, 30.0, np.float32),
               "controls": np.zeros((8, 2), np.float32)}  # fmt: skip
        return latency(lambda: policy.predict(obs, deterministic=True), repeats)


def _spaces() -> tuple[Any, Any]:
    """Our observation (a stack of eight frames and speeds) and action (the paper's force levels) spaces."""
    from gymnasium import spaces

    from agent_client.env import MAX_SPEED
    from agent_client.preprocess import FRAME_H, FRAME_W
    from protocol.constants import N_ACTIONS

    obs_space = spaces.Dict(
        {"frames": spaces.Box(0, 255, (8, FRAME_H, FRAME_W), np.uint8), "speeds": spaces.Box(0.0, MAX_SPEED, (8,), np.float32)}
    )
    return obs_space, spaces.Discrete(N_ACTIONS)


def sb3_replay_bytes(capacity: int = 1000) -> dict[str, Any]:
    """Bytes per transition of SB3's buffer for our observation (it stores obs and next obs)."""
    try:
        from stable_baselines3.common.buffers import DictReplayBuffer
    except ImportError:
        return {"error": INSTALL_HINT}
    obs_space, action_space = _spaces()
    buf = DictReplayBuffer(capacity, obs_space, action_space, device="cpu")
    arrays = [*buf.observations.values(), *buf.next_observations.values(), buf.actions, buf.rewards, buf.dones, buf.timeouts]
    return {"bytes_per_transition": sum(a.nbytes for a in arrays) / capacity}
