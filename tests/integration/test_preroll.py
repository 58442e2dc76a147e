"""The camera's pre-roll through a real server: a learned driver engages with a stack of real frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agent_client.controllers.acc import AccController
from agent_client.controllers.ddqn import DDQNController
from agent_client.drive import drive_episode
from agent_client.session import Session

MODELS = Path(__file__).resolve().parents[2] / "models"


class WarmAcc:
    """The ACC, with a history it does not need: it records what the pre-roll showed it."""

    def __init__(self, history_steps: int):
        self.history_steps, self.acc, self.seen = history_steps, AccController(), []

    def warm(self, obs):
        self.seen.append((obs["frame"], obs["gap"], obs["force"]))

    def __call__(self, obs):
        return self.acc(obs)


def test_drive_gives_a_history_reader_its_preroll_and_logs_from_frame_0(server, tmp_path):
    with Session(server) as s:
        cold = drive_episode(s, AccController(), scenario="ice", seed=1, trajectory="stopped", log=tmp_path / "cold.csv")
        acc = WarmAcc(history_steps=6)
        warm = drive_episode(s, acc, scenario="ice", seed=1, trajectory="stopped", log=tmp_path / "warm.csv")
        none = WarmAcc(history_steps=6)
        drive_episode(s, none, scenario="ice", seed=1, trajectory="stopped", preroll=0)
    assert [f for f, _, _ in acc.seen] == list(range(-6, 0)) and none.seen == []
    gaps = [g for _, g, _ in acc.seen]
    assert np.all(np.diff(gaps) < 0) and all(u == 0.0 for _, _, u in acc.seen)  # closing on the standing car, coasting
    # from frame 0 the same run, bit for bit: the log and the summary start there
    assert (tmp_path / "warm.csv").read_text() == (tmp_path / "cold.csv").read_text()
    assert (warm.steps, warm.gap_min, warm.collision) == (cold.steps, cold.gap_min, cold.collision)


def test_a_ddqn_policy_engages_with_real_frames_of_the_approach(server):
    policy = DDQNController.from_checkpoint(MODELS / "ice-eco.pt")
    assert policy.history_steps == (policy.cfg.frame_stack - 1) * policy.cfg.stack_stride > 0
    stacks = {}
    with Session(server, image_format="gray", image_size=(400, 400)) as s:
        for preroll in (0, policy.history_steps):
            obs = s.reset(scenario="ice", seed=2, trajectory="stopped", preroll=preroll)
            policy.reset()
            while obs["frame"] < 0:
                policy.warm(obs)
                obs = s.step(0.0)
            stacks[preroll] = policy.warm(obs)["frames"].numpy().copy()  # a view into the controller's rings until the next frame
    cold, warm = stacks[0], stacks[policy.history_steps]
    assert all(np.array_equal(f, cold[0]) for f in cold)  # a cold start: one frame repeated
    assert np.array_equal(warm[-1], cold[-1])  # the same frame 0
    assert len({f.tobytes() for f in warm}) == len(warm)  # eight different frames: the car growing
