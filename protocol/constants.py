"""Constants both sides of the wire agree on, defined once.

The simulator maps a normalised force to an acceleration; controllers choose among
the same force levels; metrics and rewards score the same desired gap. Each side
imports these from here (``protocol/`` imports neither side).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "A_MIN",
    "A_MAX",
    "N_ACTIONS",
    "FORCE_LEVELS",
    "FORCES",
    "DESIRED_GAP",
    "CAMERA_SIZE",
    "MIN_GAP",
    "TRAFFIC_PER_LANE",
    "TRAFFIC_PER_LANE_RANGE",
    "PHYSICS_DT",
    "SUBSTEPS",
    "CONTROL_PERIOD",
    "CAMERA_HFOV",
    "CAMERA_MOUNT_HEIGHT",
]

A_MIN = -5.5  # [m/s^2] acceleration at u = -1 (full brake), paper Sec. 4
A_MAX = 3.5  # [m/s^2] acceleration at u = +1 (full throttle)
N_ACTIONS = 21  # discrete force levels of the paper's DDQN
# u of action a: -1 + 0.1 a, rounded so that 0.0 and 1.0 are exact.
FORCE_LEVELS: tuple[float, ...] = tuple(round(-1.0 + 2.0 * a / (N_ACTIONS - 1), 1) for a in range(N_ACTIONS))
FORCES = np.asarray(FORCE_LEVELS)  # the same levels as an array: FORCES[a] is action a's u
FORCES.setflags(write=False)
DESIRED_GAP = 55.0  # [m] the paper's desired gap: the gap reward's peak and the RMSE target
CAMERA_SIZE = (400, 400)  # [px] (width, height) of the full front camera
CAMERA_HFOV = math.pi / 4  # [rad] its horizontal field of view (45 deg); the client's fixed mask is drawn for it
CAMERA_MOUNT_HEIGHT = 1.4  # [m] its height above the road (level, so the horizon is the middle row)
PHYSICS_DT = 0.02  # [s] physics step, paper Sec. 4
SUBSTEPS = 5  # physics steps per control step
CONTROL_PERIOD = PHYSICS_DT * SUBSTEPS  # [s] a default server's decision period (0.1 s, 10 Hz)
MIN_GAP = 2.0  # [m] the smallest gap a safe run may reach: the safety suite's floor and best.pt's
TRAFFIC_PER_LANE = 3  # cars in each adjacent lane (twice as many oncoming): the server's default --traffic
TRAFFIC_PER_LANE_RANGE = (0, 10)  # 10 a lane is one car every 35 m of the 350 m traffic window
SUN_ELEVATION = (0.35, 1.2)  # [rad] the range the sun's height is drawn from per episode: the server's default --sun-elevation
SUN_ELEVATION_LIMITS = (0.05, 1.5)  # [rad] any --sun-elevation range lies within these (a sun on the horizon casts endless shadows)
MAX_FOLLOWERS = 16  # a platoon server's most seats (vacc serve --followers)
