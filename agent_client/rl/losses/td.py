"""Double DQN's TD loss (van Hasselt et al. 2016), written out as CleanRL's ``dqn_atari.py``.

The main term of a run without a teacher (:data:`NAME`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from agent_client.rl.config import Config
from agent_client.rl.losses.term import Forward, LossTerm
from agent_client.rl.network import QNetwork
from agent_client.rl.replay import ReplaySamples

__all__ = ["NAME", "VALUES_NAME", "double_dqn_target", "td_target", "td_term"]

NAME = "losses/td_loss"
VALUES_NAME = "losses/q_values"  # the mean Q-value of the stored actions, logged beside it


def double_dqn_target(
    returns: torch.Tensor,
    terminated: torch.Tensor,
    next_q_online: torch.Tensor,
    next_q_target: torch.Tensor,
    discounts: torch.Tensor,
    terminal_values: torch.Tensor,
) -> torch.Tensor:
    """TD target y = G + γ^m Q_target(s', argmax_a Q_online(s', a)), cut at terminations.

    The online network picks the next action, the target network scores it.
    Truncated transitions (time limit) bootstrap like any other; only ``terminated``
    ones do not: they take ``terminal_values`` instead (0, or the terminal reward
    forever with :attr:`Config.absorbing_terminal`). One-step: G = r, γ^m = γ.

    Args:
        returns: ``[B]`` G = Σ_{k<m} γ^k r_k.
        terminated: ``[B]`` bool, the episode terminated within the m steps.
        next_q_online: ``[B, A]`` online Q-values of the observations m steps on.
        next_q_target: ``[B, A]`` target Q-values of the same.
        discounts: ``[B]`` γ^m.
        terminal_values: ``[B]`` the value after a termination.

    Returns:
        ``[B]`` targets.
    """
    next_actions = next_q_online.argmax(dim=1, keepdim=True)  # [B, 1]: online net picks
    next_values = next_q_target.gather(1, next_actions).squeeze(1)  # [B]: target net scores
    done = terminated.float()  # [B]
    bootstrap = (1.0 - done) * next_values + done * terminal_values  # [B]
    return returns + discounts * bootstrap  # [B]


@torch.no_grad()
def td_target(q: QNetwork, target: QNetwork, b: ReplaySamples, device: torch.device, gamma: float, absorbing: bool) -> torch.Tensor:
    """``[B]`` Double-DQN targets of a batch (n-step returns, the target network).

    Args:
        q: the online network (picks the next action).
        target: the target network (scores it).
        b: the replay batch.
        device: where the networks are.
        gamma: the discount per step.
        absorbing: a termination's value is its reward forever, r / (1 - γ); else 0.
    """
    next_frames, next_speeds, next_controls = b.next_frames.to(device), b.next_speeds.to(device), b.next_controls.to(device)
    next_q_online = q(next_frames, next_speeds, next_controls)  # [B, A]
    next_q_target = target(next_frames, next_speeds, next_controls)  # [B, A]
    # after a termination: the terminal reward forever, r / (1 - γ), or 0
    terminal_values = b.terminal_rewards.to(device) / (1.0 - gamma) * float(absorbing)  # [B]
    return double_dqn_target(b.returns.to(device), b.terminated.to(device), next_q_online, next_q_target, b.discounts.to(device), terminal_values)


def td_term(cfg: Config, q: QNetwork, target: QNetwork) -> LossTerm:
    """The Huber loss of the stored actions' Q-values to their Double-DQN targets."""

    def loss(out: Forward) -> torch.Tensor:
        if out.next_q is None:
            y = td_target(q, target, out.batch, out.device, cfg.gamma, cfg.absorbing_terminal)  # [B]
        else:  # a recurrent network's sequence, unrolled: its next outputs are at hand
            b, dev = out.batch, out.device
            terminal_values = b.terminal_rewards.to(dev) / (1.0 - cfg.gamma) * float(cfg.absorbing_terminal)
            with torch.no_grad():
                y = double_dqn_target(b.returns.to(dev), b.terminated.to(dev), *out.next_q, b.discounts.to(dev), terminal_values)
        return F.smooth_l1_loss(out.q_taken, y)  # Huber

    return LossTerm(NAME, None, loss)
