"""What a follower that knew the lead's future could reach: a preview frontier.

Behind a given lead, a follower trades gap error for energy. A causal controller
(a camera policy, the ACC) does not know what the lead will do next; this one does.
For a recorded lead position ``x_lead(t)`` it finds the host speed trace that minimises

    E(v) + lam * sum_k (gap_k - desired)^2 * dt,    gap_k = x_lead_k - x_k,

from the run's initial speed and gap to a given final speed, with the host's position
the trapezoid integral of its speed (as :func:`energy.trace.intervals` reads a trace).
Sweeping ``lam`` traces a frontier of (gap RMSE, energy) points that preview reaches.

The energy counted is per mile, as every energy figure here: a follower that falls
behind spends less per second but covers less road. Dinkelbach's iteration makes the
ratio a sequence of quadratic programs. Within each, E is eq. 6 (:mod:`energy.ev`)
made quadratic, and convex:

* ``l3 v a + l6 v^2 a + l7 v^3 a`` is the time derivative of ``l3 v^2/2 + l6 v^3/3 +
  l7 v^4/4``: with both end speeds fixed it is the same for every trace (eq. 6 returns
  braking energy in full, so a free final speed would bank the kinetic energy);
* ``f(v) = l0 + l1 v + l2 v^3 + l4 v^2 + l5 v^4`` is taken to second order about the
  lead's speed, its curvature floored at 0;
* ``l8 v a^2`` weighs ``a^2`` by the lead's speed, floored at 1 m/s.

The speed never goes below 0: a speed the solution would reverse is held at 0 and
the rest solved again. v_0 and v_n are given.

Each point's energy is then the exact eq. 6 energy of its trace
(:func:`energy.ev.eq6_per_mile`): a trace preview reaches, so the true optimum is at
least as good. Speed and acceleration limits are not imposed;
:attr:`PreviewPoint.accel_range` reports the extremes for a user to check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from energy.errors import TraceError
from energy.ev import EQ6_COEFFICIENTS, eq6_per_mile
from energy.units import M_PER_MI

__all__ = ["PreviewPoint", "preview_bound"]

MAX_STANDSTILL_ROUNDS = 50
MAX_RATIO_ROUNDS = 20
RATIO_TOL = 1e-6  # relative change of the energy per metre at which Dinkelbach's iteration stops
V_FLOOR = 1.0  # [m/s] the least speed that weighs a^2 (eq. 6's v a^2 vanishes at a standstill)


@dataclass(frozen=True)
class PreviewPoint:
    """One point of the preview frontier."""

    lam: float  # [1/(m^2 s)] weight of the squared gap error, kJ per (m^2 s)
    gap_rmse_m: float
    energy_kj_per_mi: float  # eq. 6, exact, of ``v``
    v: np.ndarray  # [m/s] the host speed trace
    gap: np.ndarray  # [m]
    dt: float  # [s]

    @property
    def accel_range(self) -> tuple[float, float]:
        """The least and greatest acceleration [m/s^2] of the trace (no limit was imposed)."""
        a = np.diff(self.v) / self.dt
        return float(a.min()), float(a.max())


def preview_bound(
    t: np.ndarray, x_lead: np.ndarray, v0: float, gap0: float, v_end: float, lam: float, desired_gap: float = 55.0,
    coefficients: np.ndarray | None = None,
) -> PreviewPoint:  # fmt: skip
    """The host speed trace of least (quadratic) eq. 6 energy plus ``lam`` times the squared gap error.

    Args:
        t: sample times [s], evenly spaced.
        x_lead: the lead's position at ``t`` [m].
        v0: the host's initial speed [m/s].
        gap0: the initial gap [m].
        v_end: the host's final speed [m/s] (compare with a run ending at the same speed).
        lam: the weight of the squared gap error [kJ / (m^2 s)].
        desired_gap: [m].
        coefficients: eq. 6's l0..l8 (default: the shipped fit).

    Raises:
        TraceError: uneven or too short a trace, or a weight that is not positive.
    """
    t, x_lead = np.asarray(t, float), np.asarray(x_lead, float)
    if t.ndim != 1 or len(t) < 3 or x_lead.shape != t.shape:
        raise TraceError("the preview bound needs matching time and lead-position arrays of 3 samples or more")
    dt = float(t[1] - t[0])
    if not (dt > 0 and np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9)):
        raise TraceError("the preview bound needs evenly spaced samples")
    if not lam > 0:
        raise TraceError(f"the gap weight must be > 0, got {lam}")
    c = EQ6_COEFFICIENTS if coefficients is None else np.asarray(coefficients, float)
    n = len(t) - 1
    v_lead = np.gradient(x_lead, dt)
    vr = np.maximum(0.5 * (v_lead[1:] + v_lead[:-1]), V_FLOOR)  # about the lead's speed, per interval
    # Unknowns: v_1..v_n (v_0 is given). Interval mean speeds vm = M v, accelerations a = D v.
    eye = np.eye(n + 1)
    M = 0.5 * (eye[:-1] + eye[1:])  # [n, n+1]
    D = (eye[1:] - eye[:-1]) / dt
    f1 = c[1] + 3 * c[2] * vr**2 + 2 * c[4] * vr + 4 * c[5] * vr**3
    f2 = np.maximum(6 * c[2] * vr + 2 * c[4] + 12 * c[5] * vr**2, 0.0)
    H = M.T @ (M * (f2 * dt)[:, None]) + D.T @ (D * (2 * c[8] * vr * dt)[:, None])  # [kJ s^2/m^2]
    g = M.T @ ((f1 - f2 * vr) * dt)
    # gap_k = x_lead_k - x_0 - dt * sum_{i<k} vm_i = r_k - G_k v
    G = np.vstack([np.zeros(n + 1), np.cumsum(M, axis=0) * dt])  # [n+1, n+1]
    r = x_lead - (x_lead[0] - gap0) - desired_gap
    H = H + 2 * lam * dt * (G.T @ G)
    g = g - 2 * lam * dt * (G.T @ r)
    # Energy per mile, not per second: a follower that falls behind spends less per
    # second but covers less road. Dinkelbach's iteration: minimise E - rho * distance
    # with rho the last trace's energy per metre, until rho settles.
    distance = M.T @ np.full(n, dt)  # d(distance)/dv
    rho = eq6_per_mile(t, np.maximum(v_lead, 0.0), c).energy_kj_per_mi / M_PER_MI
    for _ in range(MAX_RATIO_ROUNDS):
        v = _solve(H, g - rho * distance, v0, v_end)
        e = eq6_per_mile(t, v, c).energy_kj_per_mi
        if abs(e / M_PER_MI - rho) <= RATIO_TOL * rho:
            break
        rho = e / M_PER_MI
    gap = x_lead - (x_lead[0] - gap0) - np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])
    energy = e
    return PreviewPoint(lam, float(np.sqrt(np.mean((gap - desired_gap) ** 2))), energy, v, gap, dt)


def _solve(H: np.ndarray, g: np.ndarray, v0: float, v_end: float) -> np.ndarray:
    """argmin 1/2 v'Hv + g'v with v_0, v_n given and v >= 0: a speed the solution would
    reverse is held at 0 and the rest solved again (behind a stopped lead), until none does."""
    n1 = len(g)
    v = np.zeros(n1)
    v[0], v[-1] = v0, v_end
    free = np.ones(n1, bool)
    free[[0, -1]] = False
    for _ in range(MAX_STANDSTILL_ROUNDS):
        fixed = ~free
        v[free] = np.linalg.solve(H[np.ix_(free, free)], -(g[free] + H[np.ix_(free, fixed)] @ v[fixed]))
        reversing = free & (v < 0.0)
        if not reversing.any():
            return v
        v[reversing], free[reversing] = 0.0, False
    raise TraceError(f"the preview trace still reverses after {MAX_STANDSTILL_ROUNDS} rounds")
