"""The frame/speed stack of the DDQN input, shared by the env and the ddqn controller.

Both must build exactly the same stacks from the same frames, or a policy trained
in the env would see other inputs when it drives; so there is one implementation.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["FrameStacker", "MAX_SPEED", "stack_picks"]

MAX_SPEED = 60.0  # [m/s] upper bound of the speed observation


def stack_picks(n_history: int, frame_stack: int, stack_stride: int) -> list[int]:
    """Which of the last ``n_history`` frames (0: the oldest kept) a stack holds, oldest first:
    every ``stack_stride``-th back from the newest, the oldest pick repeated in front while
    fewer exist (an episode's start)."""
    picks = list(range(n_history - 1, -1, -stack_stride))[:frame_stack][::-1]
    return [picks[0]] * (frame_stack - len(picks)) + picks


class FrameStacker:
    """The last ``frame_stack`` frames, ``stack_stride`` control steps apart.

    At an episode start, where fewer frames exist, the oldest available pick is
    repeated in front (so the first observation is ``frame_stack`` copies of the
    first frame).

    Args:
        frame_stack: frames per observation.
        stack_stride: control steps between stacked frames.
    """

    def __init__(self, frame_stack: int = 8, stack_stride: int = 1):
        if frame_stack < 1 or stack_stride < 1:
            raise ValueError("frame_stack and stack_stride must be >= 1")
        self.frame_stack, self.stack_stride = frame_stack, stack_stride
        span = (frame_stack - 1) * stack_stride + 1
        self._history: deque[tuple[np.ndarray, float, np.ndarray | None]] = deque(maxlen=span)
        self._picks = [stack_picks(k, frame_stack, stack_stride) for k in range(1, span + 1)]  # by history length - 1

    def reset(self) -> None:
        """Forget the previous episode."""
        self._history.clear()

    def push(self, frame: np.ndarray, v_host: float, controls: np.ndarray | None = None, frames: bool = True) -> dict[str, np.ndarray]:
        """Add one preprocessed frame, its host speed [m/s] and, for action types that
        observe them, its controls (:data:`agent_client.actions.CONTROLS`); return the observation.

        Returns:
            ``{"frames": uint8 (frame_stack, H, W), "speeds": float32 (frame_stack,)}``,
            oldest first; speeds clipped to :data:`MAX_SPEED`; and, if controls were
            given, ``"controls": float32 (frame_stack, C)``. With ``frames=False``, no
            ``"frames"`` (for a caller that keeps them as the network's input itself:
            :class:`~agent_client.rl.network.ScaledFrames`).
        """
        self._history.append((frame, v_host, controls))
        history = list(self._history)
        picks = [history[i] for i in self._picks[len(history) - 1]]
        obs = {"speeds": np.array([min(v, MAX_SPEED) for _, v, _ in picks], dtype=np.float32)}
        if frames:
            obs["frames"] = np.stack([f for f, _, _ in picks])
        if controls is not None:  # np.array of the rows: a quarter of np.stack's cost
            obs["controls"] = np.array([c for _, _, c in picks if c is not None], dtype=np.float32)
        return obs
