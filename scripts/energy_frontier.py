"""How much energy a 55 m follower must spend: the ACC, causal laws, and a follower with preview.

    .venv/bin/python scripts/energy_frontier.py --seeds 200-215
    .venv/bin/python scripts/energy_frontier.py --tests
    .venv/bin/python scripts/energy_frontier.py --scenario ice --seeds 300-307

Drives the traditional ACC once per episode over UDP (`vacc drive`) to record the lead. Then, without the simulator, it replays other followers behind that same lead
with the host's own kinematics (the force map of sim_server.vehicle, 10 Hz, the speed
clamped to [0, set speed]; the replay of the ACC reproduces its logged energy, which the
script checks):

* causal laws over a grid of gains (beta, gamma), with the eco-margin gaps, through the
  ramp-fine actuator toward the law's force (what a student with the mean decision
  approximates). EV: the ACC law on a fixed 55 m gap with a 3 m/s^2 braking cap (the
  gentle 55 m teachers). ICE: the eco teachers' law, a 2 s time gap capped at 55 m.
  With ``--lag TAU`` the laws' following term sees the closing speed (host minus lead
  speed) through a first-order lag of TAU seconds, as a student that reads it from the
  camera does (agent_client.controllers.acc.LateClosing; their collision-avoidance
  limit reads the true speeds);
* with ``--copy``, lead copies: a follower handed the lead's true acceleration and speed
  TAU seconds late that copies them, with a weak pull toward 55 m
  (:class:`LeadCopy`); at TAU = 0 it is the best a causal follower can know, an upper
  bound on what perception could give a student;
* with ``--mpc`` (EV only), predictive followers: told the lead's speed and acceleration
  as the copies are, they re-plan every step with preview_bound over the next 10 s of a
  predicted lead, whose acceleration fades over 5 s, and take the plan's first step
  (:class:`PredictiveFollower`), at the copies' lags;
* preview (EV only; its model is eq. 6): energy.frontier.preview_bound over a grid of gap
  weights, from the ACC's initial speed and gap to its final speed: what a follower that
  knew the lead's whole future could reach.

Prints, per follower, the gap RMSE to 55 m (mean and worst over episodes) and the energy
(EV: eq. 6; ICE: the Corolla's CMEM fuel) as a ratio to the ACC's on the same episode;
writes OUT/summary.json and OUT/energy-frontier.png.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import subprocess
import sys
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from agent_client.actions import FineRamp
from agent_client.controllers.acc import AccController, LateClosing
from agent_client.rewards import CONTROL_PERIOD as DT
from agent_client.rewards import ECO_TIME_GAP
from agent_client.rl.teachers import MARGIN_GAPS, REGISTRY
from energy.cmem import COROLLA_2022
from energy.cmem import per_mile as cmem_per_mile
from energy.errors import TraceError
from energy.ev import eq6_per_mile
from energy.frontier import preview_bound
from protocol.constants import A_MAX, A_MIN, DESIRED_GAP
from protocol.force import accel_of_force
from protocol.scenarios import DEFAULT_SET_SPEED, TEST_TRAJECTORIES
from sim_server.vehicle import advance_speed
from vacc.runs import parse_seeds

BETAS = {"ev": (0.1, 0.2, 0.3, 0.4, 0.5), "ice": (0.1, 0.125, 0.15, 0.2)}
GAMMAS = {"ev": (1.2, 2.0, 3.0, 4.0), "ice": (0.3, 0.6, 1.0, 2.0)}
UNIT = {"ev": "kJ/mi", "ice": "g/mi"}
TARGET_RMSE = {"ev": 5.1, "ice": 3.4}  # [m] issue #15's gap RMSE bound on each episode
LAMS = (0.001, 0.003, 0.01, 0.03, 0.1)
COPY_LAGS = (0.0, 0.5, 1.0)  # [s] how late the lead copies see the lead
LIMITS = [0.0, 12.0, 0.88, 1.12]  # the figure's axes: gap RMSE [m], energy ratio
COPY_SPEED_GAINS = (0.5, 1.0, 2.0)  # [1/s]
COPY_GAP_GAINS = (0.02, 0.05, 0.1)  # [1/s^2]
MPC_HORIZON = 10.0  # [s] how far ahead the predictive followers plan
MPC_FADE = 5.0  # [s] the time constant over which they expect the lead's acceleration to fade
MPC_LAMS = (0.01, 0.015, 0.02, 0.03)  # their gap weights [kJ/(m^2 s)]
FALLBACK_SPEED_GAIN, FALLBACK_GAP_GAIN = 1.0, 0.1  # [1/s], [1/s^2] the lead copy they fall back on at a standstill
DECEL_CAP = REGISTRY["acc-55-gentle"].decel_cap  # [m/s^2] the gentle teachers' braking cap


def energy_per_mile(scenario: str, t: np.ndarray, v: np.ndarray) -> float:
    """EV: eq. 6 [kJ/mi]; ICE: the Corolla's CMEM fuel [g/mi]."""
    return eq6_per_mile(t, v).energy_kj_per_mi if scenario == "ev" else cmem_per_mile(t, v, COROLLA_2022).fuel_g_per_mi


def teacher_law(scenario: str, beta: float, gamma: float) -> AccController:
    """The law of the grid at (beta, gamma), with the eco-margin gaps (see the module docstring)."""
    d_safe, d_min = MARGIN_GAPS
    if scenario == "ev":
        return AccController(fixed_gap=DESIRED_GAP, beta=beta, gamma=gamma, decel_cap=DECEL_CAP, d_safe=d_safe, d_min=d_min)
    return AccController(t_gap=ECO_TIME_GAP, max_gap=DESIRED_GAP, beta=beta, gamma=gamma, d_safe=d_safe, d_min=d_min)


class LeadCopy:
    """a = a_lead(t - lag) + k_v (v_lead(t - lag) - v) + k_g (gap - 55 m), as a force.

    Not a controller a camera student could be taught: it is handed the lead's
    acceleration. It asks how little a 55 m follower could spend if it knew the lead's
    present motion, which no law of the grid above is told."""

    def __init__(self, lag: float, k_v: float, k_g: float):
        self.k_v, self.k_g = k_v, k_g
        self.late: deque[tuple[float, float]] = deque(maxlen=round(lag / DT) + 1)

    def __call__(self, obs: dict[str, float]) -> float:
        self.late.append((obs["a_lead"], obs["v_lead"]))
        a_lead, v_lead = self.late[0]  # lag seconds ago (the first seen, until then)
        a = a_lead + self.k_v * (v_lead - obs["v_host"]) + self.k_g * (obs["gap"] - DESIRED_GAP)
        return min(1.0, a / A_MAX) if a >= 0.0 else max(-1.0, a / -A_MIN)


class PredictiveFollower:
    """Receding-horizon preview on a predicted lead: every step, the host speed trace of
    least eq. 6 energy plus ``lam`` x squared gap error over the next ``horizon`` s
    (energy.frontier.preview_bound), behind the lead as predicted from its speed and
    acceleration ``lag`` s before, the acceleration fading over ``fade`` s; it takes the
    plan's first step. The gap is read as it is now.

    Like :class:`LeadCopy` it is handed the lead's acceleration, so it is a bound, not a
    teacher. Standing behind a stopped lead, where energy per mile is undefined, it
    follows as a copy of the same (late) lead state does."""

    def __init__(self, lag: float, lam: float, horizon: float = MPC_HORIZON, fade: float = MPC_FADE):
        self.lam, self.fade = lam, fade
        self.late: deque[tuple[float, float]] = deque(maxlen=round(lag / DT) + 1)
        self.t = np.arange(round(horizon / DT) + 1) * DT

    def _ahead(self, a: float, v: float, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The lead's displacement [m] and speed [m/s] ``tau`` s after the state (a, v)."""
        faded = 1.0 - np.exp(-tau / self.fade)
        return v * tau + a * self.fade * (tau - self.fade * faded), v + a * self.fade * faded

    def __call__(self, obs: dict[str, float]) -> float:
        self.late.append((obs["a_lead"], obs["v_lead"]))
        a_lead, v_lead = self.late[0]
        seen = (len(self.late) - 1) * DT  # how long ago that state was
        x_then, _ = self._ahead(a_lead, v_lead, np.array([seen]))
        x, v = self._ahead(a_lead, v_lead, self.t + seen)
        x_lead = np.maximum.accumulate(obs["gap"] + x - x_then[0])  # the host at 0; a lead does not back up
        try:
            plan = preview_bound(self.t, x_lead, obs["v_host"], obs["gap"], max(float(v[-1]), 0.0), self.lam)
            a = (plan.v[1] - obs["v_host"]) / DT
        except TraceError:  # a plan that stands still: no energy per mile to weigh; copy, as late
            a = a_lead + FALLBACK_SPEED_GAIN * (v_lead - obs["v_host"]) + FALLBACK_GAP_GAIN * (obs["gap"] - DESIRED_GAP)
        return min(1.0, a / A_MAX) if a >= 0.0 else max(-1.0, a / -A_MIN)


def record(trajectory: str, seed: int, out: Path, name: str = "acc", checkpoint: str | None = None, scenario: str = "ev") -> dict[str, np.ndarray]:
    """Drive the ACC (or a DDQN checkpoint) over UDP; the log's columns, with the lead's position."""
    log = out / "logs" / f"{name}-{trajectory}-{seed}.csv"
    log.parent.mkdir(parents=True, exist_ok=True)
    if not log.exists():
        who = ["--controller", "acc"] if checkpoint is None else ["--controller", "ddqn", "--checkpoint", checkpoint]
        cmd = [sys.executable, "-m", "vacc", "drive", *who, "--scenario", scenario, "--trajectory", trajectory,
               "--seed", str(seed), "--log", str(log), "--quiet"]  # fmt: skip
        subprocess.run(cmd, check=True)
    with log.open() as f:
        rows = list(csv.DictReader(f))
    run = {k: np.array([float(r[k]) for r in rows]) for k in ("t", "v_host", "v_lead", "a_lead", "gap")}
    x_host = np.concatenate([[0.0], np.cumsum(0.5 * (run["v_host"][1:] + run["v_host"][:-1]) * np.diff(run["t"]))])
    run["x_lead"] = x_host + run["gap"]
    return run


def replay(run: dict[str, np.ndarray], law: AccController | LeadCopy | PredictiveFollower, ramp: bool, lag: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Host speed and gap behind the recorded lead under ``law`` (through the ramp-fine
    actuator if ``ramp``), the law's following term seeing the closing speed through a
    first-order lag of ``lag`` seconds (0: as it is)."""
    t, x_lead = run["t"], run["x_lead"]
    v, x = float(run["v_host"][0]), float(x_lead[0] - run["gap"][0])
    actuator = FineRamp()
    vs, gaps = [v], [x_lead[0] - x]
    driver: AccController | LeadCopy | PredictiveFollower | LateClosing = LateClosing(law, lag, DT) if lag > 0.0 and isinstance(law, AccController) else law
    for k in range(len(t) - 1):
        u = driver({"gap": x_lead[k] - x, "v_host": v, "v_lead": run["v_lead"][k], "a_lead": run["a_lead"][k], "set_speed": DEFAULT_SET_SPEED})
        if ramp:
            u = actuator.force_toward(u)
        v_next = advance_speed(v, accel_of_force(u), DT, DEFAULT_SET_SPEED)
        x += 0.5 * (v + v_next) * DT
        v = v_next
        vs.append(v)
        gaps.append(x_lead[k + 1] - x)
    return np.array(vs), np.array(gaps)


def rmse(gap: np.ndarray) -> float:
    return float(np.sqrt(np.mean((gap - DESIRED_GAP) ** 2)))


def floats(p: argparse.ArgumentParser, name: str, text: str) -> list[float]:
    """Comma-separated numbers >= 0, or the parser's one-line error naming the option."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        p.error(f"{name}: comma-separated numbers, e.g. 0,0.2; got {text!r}")
    if not all(math.isfinite(x) and x >= 0.0 for x in values):
        p.error(f"{name}: each must be finite and >= 0; got {text!r}")
    return values


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", choices=sorted(UNIT), default="ev", help="the host vehicle (default ev)")
    p.add_argument("--seeds", default="200-215", help="random episodes, e.g. 200-215")
    p.add_argument("--tests", action="store_true", help="the test trajectories test-1..4 (seed 0) instead")
    p.add_argument("--out", default=None, help="output folder (default runs/energy-frontier-{random,tests}, with -ice for the ICE car)")
    p.add_argument("--betas", default=None, help="gap gains [1/s^2], comma-separated (default: the scenario's grid)")
    p.add_argument("--gammas", default=None, help="speed-difference gains [1/s], comma-separated (default: the scenario's grid)")
    p.add_argument("--lag", type=float, default=0.0, help="[s] the laws see the closing speed through a first-order lag of this (default 0)")
    p.add_argument("--copy", action="store_true", help="also the lead copies (LeadCopy) over their grid of lags and gains")
    p.add_argument("--mpc", action="store_true", help="(EV) also the predictive followers (PredictiveFollower) at the --copy-lags, over their gap weights")
    p.add_argument("--copy-speed-gains", default=",".join(map(str, COPY_SPEED_GAINS)), help="[1/s] (--copy) k_v, comma-separated (default %(default)s)")
    p.add_argument("--copy-gap-gains", default=",".join(map(str, COPY_GAP_GAINS)), help="[1/s^2] (--copy) k_g, comma-separated (default %(default)s)")
    p.add_argument("--copy-lags", default=",".join(map(str, COPY_LAGS)), help="[s] (--copy, --mpc) how late the lead copies see the lead, to the nearest control step, comma-separated (default %(default)s)")
    p.add_argument("--lams", default=",".join(map(str, LAMS)), help="preview gap weights [kJ/(m^2 s)] (EV only)")
    p.add_argument("--limits", default=",".join(map(str, LIMITS)), help="the figure's axes X0,X1,Y0,Y1: gap RMSE [m], energy ratio (default %(default)s)")
    p.add_argument("--replot", action="store_true", help="only redraw OUT/energy-frontier.png from OUT/summary.json (with --limits)")
    p.add_argument("models", nargs="*", metavar="NAME=CHECKPOINT", help="learned drivers to drive over UDP on the same episodes and mark")
    a = p.parse_args()
    limits = floats(p, "--limits", a.limits)
    if len(limits) != 4 or not (limits[0] < limits[1] and limits[2] < limits[3]):
        p.error(f"--limits: X0,X1,Y0,Y1 with X0 < X1 and Y0 < Y1; got {a.limits!r}")
    if not a.lag >= 0.0:
        p.error(f"--lag: a lag is a time, >= 0 s; got {a.lag:g}")
    if a.mpc and a.scenario != "ev":
        p.error("--mpc: the predictive followers plan on eq. 6, the EV's energy; use --scenario ev")
    betas = floats(p, "--betas", a.betas) if a.betas else BETAS[a.scenario]
    gammas = floats(p, "--gammas", a.gammas) if a.gammas else GAMMAS[a.scenario]
    lams = floats(p, "--lams", a.lams)
    if not all(lam > 0.0 for lam in lams):
        p.error(f"--lams: each preview gap weight must be > 0; got {a.lams!r}")
    copy_lags, k_vs, k_gs = (floats(p, name, text) for name, text in (("--copy-lags", a.copy_lags), ("--copy-speed-gains", a.copy_speed_gains), ("--copy-gap-gains", a.copy_gap_gains)))
    episodes = [(t, 0) for t in TEST_TRAJECTORIES] if a.tests else [("random", s) for s in parse_seeds(a.seeds)]
    sc, unit = a.scenario, UNIT[a.scenario]
    out = Path(a.out or f"runs/energy-frontier-{'tests' if a.tests else 'random'}{'-ice' if sc == 'ice' else ''}")
    where = ("EV test windows 1-4" if sc == "ev" else "ICE test-1..4") if a.tests else f"random {sc.upper()} episodes {a.seeds}"
    ylabel = "energy / the ACC's (eq. 6)" if sc == "ev" else "fuel / the ACC's (Corolla CMEM)"
    if a.replot:
        try:
            rows = json.loads((out / "summary.json").read_text())["rows"]
        except (OSError, ValueError, KeyError) as exc:
            raise SystemExit(f"{out / 'summary.json'}: no summary of an earlier run to redraw ({exc})") from None
        plot(rows, out / "energy-frontier.png", where, ylabel, TARGET_RMSE[sc], limits)
        print(f"wrote {out / 'energy-frontier.png'}")
        return
    out.mkdir(parents=True, exist_ok=True)
    runs = [record(t, s, out, scenario=sc) for t, s in episodes]

    acc = []
    for run in runs:
        e = energy_per_mile(sc, run["t"], run["v_host"])
        v, _ = replay(run, AccController(), ramp=False)
        if not np.allclose(v, run["v_host"], rtol=0, atol=1e-9):
            raise SystemExit("the kinematic replay does not reproduce the ACC's logged run: the simulator's host model changed")
        acc.append(e)
    rows: list[dict[str, Any]] = [{"follower": "acc", "rmse": [rmse(r["gap"]) for r in runs], "energy": acc}]
    for item in a.models:
        name, _, path = item.partition("=")
        driven = [record(t, s, out, name, path, sc) for t, s in episodes]
        rows.append({"follower": name, "model": path, "rmse": [rmse(r["gap"]) for r in driven],
                     "energy": [energy_per_mile(sc, r["t"], r["v_host"]) for r in driven]})  # fmt: skip
    for beta, gamma in itertools.product(betas, gammas):
        done = [replay(r, teacher_law(sc, beta, gamma), ramp=True, lag=a.lag) for r in runs]
        rows.append({"follower": f"law beta {beta:g} gamma {gamma:g}" + (f" lag {a.lag:g} s" if a.lag else ""), "beta": beta, "gamma": gamma, "lag": a.lag,
                     "rmse": [rmse(g) for _, g in done], "energy": [energy_per_mile(sc, r["t"], v) for r, (v, _) in zip(runs, done, strict=True)]})  # fmt: skip
    for lag, k_v, k_g in itertools.product(copy_lags, k_vs, k_gs) if a.copy else ():
        done = [replay(r, LeadCopy(lag, k_v, k_g), ramp=True) for r in runs]
        rows.append({"follower": f"copy lag {lag:g} s k_v {k_v:g} k_g {k_g:g}", "copy_lag": lag, "k_v": k_v, "k_g": k_g,
                     "rmse": [rmse(g) for _, g in done], "energy": [energy_per_mile(sc, r["t"], v) for r, (v, _) in zip(runs, done, strict=True)]})  # fmt: skip
    for lag, lam in itertools.product(copy_lags, MPC_LAMS) if a.mpc else ():
        done = [replay(r, PredictiveFollower(lag, lam), ramp=True) for r in runs]
        rows.append({"follower": f"predictive lag {lag:g} s lam {lam:g}", "mpc_lag": lag, "mpc_lam": lam,
                     "rmse": [rmse(g) for _, g in done], "energy": [energy_per_mile(sc, r["t"], v) for r, (v, _) in zip(runs, done, strict=True)]})  # fmt: skip
    for lam in lams if sc == "ev" else ():
        pts = [preview_bound(r["t"], r["x_lead"], r["v_host"][0], r["gap"][0], r["v_host"][-1], lam) for r in runs]
        rows.append({"follower": f"preview lam {lam:g}", "lam": lam, "rmse": [q.gap_rmse_m for q in pts], "energy": [q.energy_kj_per_mi for q in pts],
                     "accel_range": [min(q.accel_range[0] for q in pts), max(q.accel_range[1] for q in pts)]})  # fmt: skip
    for row in rows:
        row["ratio"] = float(np.mean(np.array(row["energy"]) / np.array(acc)))
        extra = f"  accel {row['accel_range'][0]:.1f}..{row['accel_range'][1]:.1f} m/s^2" if "accel_range" in row else ""
        print(f"{row['follower']:28} gap RMSE {np.mean(row['rmse']):6.2f} / {max(row['rmse']):6.2f} m   energy {np.mean(row['energy']):7.1f} {unit}  x{row['ratio']:.3f} of the ACC{extra}")
    (out / "summary.json").write_text(json.dumps({"episodes": episodes, "rows": rows}, indent=1) + "\n")
    plot(rows, out / "energy-frontier.png", where, ylabel, TARGET_RMSE[sc], limits)
    print(f"wrote {out / 'summary.json'} and {out / 'energy-frontier.png'}")


def plot(rows: list[dict[str, Any]], path: Path, title: str, ylabel: str, target: float, limits: list[float] = LIMITS) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5))
    preview = [r for r in rows if "lam" in r]
    if preview:
        ax.plot([np.mean(r["rmse"]) for r in preview], [r["ratio"] for r in preview], "k-o", label="preview (knows the lead's future)")
    laws = [r for r in rows if "beta" in r]
    for gamma in sorted({r["gamma"] for r in laws}):
        pts = sorted((np.mean(r["rmse"]), r["ratio"]) for r in laws if r["gamma"] == gamma)
        betas = ", ".join(f"{r['beta']:g}" for r in laws if r["gamma"] == gamma)
        ax.plot(*zip(*pts, strict=True), "--s", ms=4, label=f"law, gamma {gamma:g} (beta {betas})")
    for lag in sorted({r["copy_lag"] for r in rows if "copy_lag" in r}):
        pts = sorted((np.mean(r["rmse"]), r["ratio"]) for r in rows if r.get("copy_lag") == lag)
        ax.plot(*zip(*pts, strict=True), ":^", ms=4, label=f"lead copy, told the lead's acceleration {lag:g} s late")
    for lag in sorted({r["mpc_lag"] for r in rows if "mpc_lag" in r}):
        pts = sorted((np.mean(r["rmse"]), r["ratio"]) for r in rows if r.get("mpc_lag") == lag)
        ax.plot(*zip(*pts, strict=True), "-.v", ms=4, label=f"predictive, told the lead's acceleration {lag:g} s late")
    for r in rows:
        if "model" in r:
            ax.plot(np.mean(r["rmse"]), r["ratio"], "*", ms=12, label=f"{r['follower']} (driven from the camera)")
    acc = rows[0]
    ax.axhline(1.0, color="tab:red", lw=1)
    ax.annotate(f"ACC (1.8 s gap): gap RMSE {np.mean(acc['rmse']):.1f} m", (0.98, 1.0), xycoords=("axes fraction", "data"), ha="right", va="bottom", color="tab:red")
    ax.axvline(target, color="gray", lw=0.8, ls=":")
    ax.set_xlim(*limits[:2])
    ax.set_ylim(*limits[2:])
    ax.set_xlabel("gap RMSE to 55 m, mean over episodes [m]")
    ax.set_ylabel(ylabel)
    ax.set_title(f"What a 55 m follower spends: {title}")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: the points crowd the inside
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    main()
