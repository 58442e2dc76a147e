"""The learned driver: a DDQN checkpoint's greedy policy on raw session observations."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from agent_client.actions import make_action_type
from agent_client.preprocess import preprocess
from agent_client.rl.actor_critic import policy_of
from agent_client.rl.checkpoint import load_policy
from agent_client.rl.config import Config
from agent_client.rl.network import Decision, QNetwork, ScaledFrames
from agent_client.stacker import FrameStacker

__all__ = ["DDQNController"]


class DDQNController:
    """Greedy DDQN driver (for ``vacc drive`` and ``vacc evaluate``); with a continuous
    action's checkpoint, the actor-critic's actor (:mod:`agent_client.rl.actor_critic`).

    Keeps its own frame/speed stack with the env's :class:`FrameStacker` (its frames as the
    network's input, :class:`~agent_client.rl.network.ScaledFrames`), so it sees
    exactly what the network saw in training, and decides through
    :class:`~agent_client.rl.network.Policy` with the checkpoint's decision rule, the
    trainer's own inference path.
    Uses the camera image and the host speed of the observation only, and, for the
    held-force action types ("steps", "ramp", "ramp-fine"), its own last force and the set speed the driver chose.

    A network with a gap head (``--aux-gap``) also estimates the gap from the same
    frames, and one with a closing head (``--aux-closing``) the closing speed; ``vacc
    drive`` logs them as ``gap_est`` and ``closing_est`` (:attr:`log_columns`). They are
    outputs to inspect, never used to decide.

    Args:
        q: the Q-network.
        cfg: its config (stack size, stride, zoom).
    """

    name = "ddqn"

    def __init__(self, q: QNetwork, cfg: Config):
        self.q, self.cfg = q.eval(), cfg
        self.policy = policy_of(self.q, cfg)
        self.log_columns: tuple[str, ...] = tuple(c for c, head in (("gap_est", q.gap_head), ("closing_est", q.closing_head)) if head is not None)
        self.log_values: tuple[float, ...] = ()  # of the last decision, one per log column
        self.stacker = FrameStacker(cfg.frame_stack, cfg.stack_stride)
        self.frames = ScaledFrames(cfg.frame_stack, cfg.stack_stride)
        self.actions = make_action_type(cfg.action)

    @classmethod
    def from_checkpoint(cls, path: str | Path) -> DDQNController:
        """Load from a checkpoint.

        Raises:
            InputFileError: see :func:`~agent_client.rl.checkpoint.load_policy`.
        """
        return cls(*load_policy(path))

    def reset(self) -> None:
        """Forget the previous episode's frames (and release the held force)."""
        self.stacker.reset()
        self.frames.reset()
        self.actions.reset()
        self.policy.reset()

    @property
    def history_steps(self) -> int:
        """Control steps of camera history its stack spans: the pre-roll ``vacc drive`` gives it."""
        return (self.cfg.frame_stack - 1) * self.cfg.stack_stride

    def warm(self, obs: dict[str, Any]) -> dict[str, Any]:
        """Stack a frame from before it engages (the pre-roll), deciding nothing; returns the
        stack (its frames scaled, valid until the next frame)."""
        from agent_client.session import Session

        image = Session.image(obs)
        if image is None:
            raise ValueError("the ddqn controller needs camera images; open the session with image_format='gray'")
        controls = None
        if self.actions.n_controls:
            self.actions.observe(float(obs["accel"]))  # anti-windup, as in the env
            controls = self.actions.controls(float(obs["set_speed"]))
        frame = preprocess(image, self.cfg.zoom)
        stacked: dict[str, Any] = self.stacker.push(frame, float(obs["v_host"]), controls, frames=False)
        stacked["frames"] = self.frames.push(frame)
        return stacked

    def act(self, stacked: dict[str, Any]) -> Decision:
        """The decision for a stacked observation (frames, speeds and, if observed, controls)."""
        return self.policy(stacked)

    def _with_heads(self, stacked: dict[str, Any]) -> tuple[torch.Tensor, tuple[float, ...]]:
        """The outputs ``[A]`` and the heads' estimates (:attr:`log_columns`: the gap [m], the
        closing speed [m/s]) for a stacked observation."""
        q, gap, closing = self.policy.outputs(stacked["frames"], stacked["speeds"], stacked.get("controls"))  # a recurrent state steps on
        estimates = (None if gap is None else QNetwork.gap_estimate(gap), None if closing is None else QNetwork.closing_estimate(closing))
        return q[0], tuple(float(e[0]) for e in estimates if e is not None)

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force u in [-1, 1] for a session observation carrying a gray/RGB image."""
        stacked = self.warm(obs)
        if self.log_columns:  # one pass for the decision and the estimates
            q, self.log_values = self._with_heads(stacked)
            d = self.policy.decide(q, stacked.get("controls"))
        else:
            d = self.act(stacked)
        if d.continuous is not None:  # the actor-critic's target force
            return self.actions.force(d.continuous)  # type: ignore[arg-type]
        return self.actions.force(d.action) if d.target is None else self.actions.force_toward(d.target)  # type: ignore[attr-defined]
