"""Calibrate the traditional ACC to real followers: replay a recorded leader, fit the spacing.

For one follower of an OpenACC file at a time, the recorded speed of the car directly
ahead drives a simulated follower that starts at the follower's recorded speed and
spacing; its gains ``beta``, ``gamma`` and time gap ``t_gap`` are fitted so that its
spacing matches the recorded ``IVS`` in RMSE. The follower is the law of
:class:`agent_client.controllers.acc.AccController` (its limits included) on the
world's vehicle model, written over arrays so that a whole grid of parameter sets is
simulated at once (:func:`acc_accel`, checked against the controller in the tests).

The fit is a grid over the three parameters, then Levenberg-Marquardt from its
:data:`LM_STARTS` best points: the gains' valley is long and shallow (a low beta with a
high gamma follows almost as well), where a grid that zooms in gets lost. scipy is not
a dependency, and a batch of a few hundred parameter sets costs about what one does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agent_client.controllers.acc import V_STANDING, AccController
from energy.openacc import OpenAccRun
from protocol.constants import A_MAX, A_MIN, PHYSICS_DT, SUBSTEPS
from protocol.scenarios import DEFAULT_SET_SPEED

__all__ = ["AccFit", "acc_accel", "replay_spacing", "fit_follower", "GRID"]

# Search ranges: (low, high) of beta [1/s^2], gamma [1/s], t_gap [s].
GRID = ((0.005, 1.0), (0.0, 2.0), (0.3, 4.0))
DEFAULT_LAW = AccController()  # the shipped ACC's settings besides the fitted three
GRID_POINTS = 8  # per parameter in the first grid
LM_STARTS = 4  # the best grid points refined by Levenberg-Marquardt, all at once
LM_ITERATIONS = 25
LM_TOLERANCE = 1e-6  # stop when no start lowers its mean squared error by this share
LM_DAMPINGS = (1e-3, 1e-2, 1e-1, 1.0, 10.0)  # tried together in every iteration


@dataclass(frozen=True)
class AccFit:
    """The ACC fitted to one real follower."""

    file: str
    follower: int  # 1-based position behind the lead (car follower + 1 of the file)
    vehicle: str  # the follower's car model
    beta: float  # [1/s^2]
    gamma: float  # [1/s]
    t_gap: float  # [s]
    rmse_m: float  # [m] spacing RMSE over the recorded samples
    samples: int  # recorded spacing samples compared


def acc_accel(
    gap: np.ndarray, v: np.ndarray, v_lead: np.ndarray | float, a_lead: np.ndarray | float,
    beta: np.ndarray, gamma: np.ndarray, t_gap: np.ndarray, law: AccController = DEFAULT_LAW,
    set_speed: float = DEFAULT_SET_SPEED,
) -> np.ndarray:
    """The acceleration [m/s^2] the ACC commands, over arrays (any broadcastable shapes).

    ``beta``, ``gamma`` and ``t_gap`` replace ``law``'s; its other settings hold
    (d_safe, d_min, the collision-avoidance limit, the set-speed cap, the force map's range).
    """
    d_ref = np.minimum(np.maximum(v * t_gap, law.d_safe), law.max_gap)
    a = np.maximum(beta * (gap - d_ref) + gamma * (v_lead - v), -law.decel_cap)
    a = np.minimum(a, law.k_speed * (set_speed - v))
    closing = v - v_lead  # [m/s]
    d_aim = np.where(v_lead < V_STANDING, law.d_safe, law.d_min)
    engage = (closing > 0.0) & (gap - d_aim < law.ttc_engage * closing)
    a_safe = np.minimum(a_lead, 0.0) - closing**2 / (2.0 * np.maximum(gap - d_aim, 0.1))
    a = np.where(engage, np.minimum(a, a_safe), a)
    return np.clip(a, A_MIN, A_MAX)


def replay_spacing(
    v_lead: np.ndarray, gap0: float, v0: float, beta: np.ndarray, gamma: np.ndarray, t_gap: np.ndarray,
    law: AccController = DEFAULT_LAW, set_speed: float = DEFAULT_SET_SPEED,
) -> np.ndarray:
    """Spacing [m] of simulated followers behind a leader sampled every control period.

    Args:
        v_lead: the leader's speed [m/s] per control period (0.1 s), finite.
        gap0, v0: the follower's spacing [m] and speed [m/s] at the first sample.
        beta, gamma, t_gap: one value per parameter set, shape [P].

    Returns:
        Spacing [P, len(v_lead)], the first column ``gap0``.
    """
    p = np.broadcast(beta, gamma, t_gap).shape
    dt = PHYSICS_DT
    gap, v = np.full(p, float(gap0)), np.full(p, float(v0))
    out = np.empty((*p, len(v_lead)))
    out[..., 0] = gap
    a_lead = 0.0
    ramp = np.arange(1, SUBSTEPS + 1) * dt  # [s] the substeps' times into the period
    frac = np.arange(1, SUBSTEPS + 1) / SUBSTEPS
    for k in range(1, len(v_lead)):
        a = acc_accel(gap, v, v_lead[k - 1], a_lead, beta, gamma, t_gap, law, set_speed)
        # Constant a over the period: clipping each substep's speed is clipping the ramp.
        vs = np.clip(v[..., None] + a[..., None] * ramp, 0.0, set_speed)  # [..., SUBSTEPS]
        lead = v_lead[k - 1] + (v_lead[k] - v_lead[k - 1]) * frac  # linear between samples, as lead_profile
        gap = gap + np.sum(lead - vs, axis=-1) * dt
        v = vs[..., -1]
        a_lead = (v_lead[k] - v_lead[k - 1]) / (SUBSTEPS * dt)
        out[..., k] = gap
    return out


def _rmse(sim: np.ndarray, ivs: np.ndarray) -> np.ndarray:
    ok = np.isfinite(ivs)
    return np.sqrt(np.mean((sim[..., ok] - ivs[ok]) ** 2, axis=-1))


def _grid(lo: np.ndarray, hi: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    axes = [np.linspace(a, b, n) for a, b in zip(lo, hi, strict=True)]
    return tuple(g.ravel() for g in np.meshgrid(*axes, indexing="ij"))


def _fill(x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    idx = np.arange(x.size)
    return np.interp(idx, idx[ok], x[ok])


def _levenberg_marquardt(residuals: Callable[[np.ndarray], np.ndarray], starts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Least squares from several starts at once; the best end point [3].

    Each iteration simulates, in one batch, every start and its finite-difference
    neighbours (the Jacobian), then in a second batch the steps of every damping in
    :data:`LM_DAMPINGS`; each start keeps its best step if it lowers its error.
    """
    p = starts.copy()  # [K, 3]
    h = (hi - lo) * 1e-4  # [3] finite-difference steps
    for _ in range(LM_ITERATIONS):
        k = p.shape[0]
        probe = np.concatenate([p, *(p + h * e for e in np.eye(3))])  # [4K, 3]
        r = residuals(probe).reshape(4, k, -1)  # [4, K, M]
        jac = np.stack([(r[j + 1] - r[0]) / h[j] for j in range(3)], axis=-1)  # [K, M, 3]
        jtj, jtr = np.einsum("kmi,kmj->kij", jac, jac), np.einsum("kmi,km->ki", jac, r[0])
        steps = np.stack([np.linalg.solve(jtj[i] + lam * np.diag(np.diag(jtj[i])) + 1e-12 * np.eye(3), -jtr[i])
                          for lam in LM_DAMPINGS for i in range(k)])  # [D * K, 3]
        cand = np.clip(np.tile(p, (len(LM_DAMPINGS), 1)) + steps, lo, hi)
        e_cand = np.mean(residuals(cand) ** 2, axis=1).reshape(len(LM_DAMPINGS), k)
        e_cand = np.where(np.isfinite(e_cand), e_cand, np.inf)
        e_now = np.mean(r[0] ** 2, axis=1)
        j = np.argmin(e_cand, axis=0)
        better = e_cand[j, np.arange(k)] < e_now
        p = np.where(better[:, None], cand.reshape(len(LM_DAMPINGS), k, 3)[j, np.arange(k)], p)
        gain = (e_now - e_cand[j, np.arange(k)]) / np.maximum(e_now, 1e-30)
        if not better.any() or gain.max() < LM_TOLERANCE:
            break
    e = np.mean(residuals(p) ** 2, axis=1)
    return p[int(np.argmin(np.where(np.isfinite(e), e, np.inf)))]


def fit_follower(run: OpenAccRun, follower: int, law: AccController = DEFAULT_LAW) -> AccFit:
    """Fit beta, gamma and t_gap to follower ``follower`` (1-based) of an OpenACC run.

    Raises:
        ValueError: no such follower, or too few recorded samples (under 100).
    """
    if not 1 <= follower < run.n_cars:
        raise ValueError(f"{run.name} has followers 1..{run.n_cars - 1}, not {follower}")
    v_lead, v_f, ivs = _fill(run.speed[follower - 1]), run.speed[follower], run.ivs[follower - 1]
    first = int(np.argmax(np.isfinite(v_f) & np.isfinite(ivs)))
    v_lead, v_f, ivs = v_lead[first:], v_f[first:], ivs[first:]
    if np.isfinite(ivs).sum() < 100:
        raise ValueError(f"{run.name} follower {follower}: too few recorded spacings")
    lo, hi = np.array([g[0] for g in GRID]), np.array([g[1] for g in GRID])
    ok = np.isfinite(ivs)

    def residuals(points: np.ndarray) -> np.ndarray:  # [P, 3] -> [P, samples]
        beta, gamma, t_gap = points.T
        return replay_spacing(v_lead, ivs[0], v_f[0], beta, gamma, t_gap, law=law)[:, ok] - ivs[ok]

    points = np.stack(_grid(lo, hi, GRID_POINTS), axis=1)  # [P, 3]
    err = np.sqrt(np.mean(residuals(points) ** 2, axis=1))
    starts = points[np.argsort(np.where(np.isfinite(err), err, np.inf))[:LM_STARTS]]
    best_p = _levenberg_marquardt(residuals, starts, lo, hi)
    best = (*best_p, float(np.sqrt(np.mean(residuals(best_p[None])[0] ** 2))))
    assert best is not None
    beta, gamma, t_gap = (float(b) for b in best[:3])
    return AccFit(run.name, follower, run.vehicles[follower], beta, gamma, t_gap, best[3], int(np.isfinite(ivs).sum()))
