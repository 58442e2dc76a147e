"""``vacc platoon``: a platoon over UDP, one client process per seat, and its string-stability figures.

It spawns a platoon server (``vacc serve --followers N``), or joins a running one with
``--server``, and one ``vacc drive --seat i`` per follower, nearest the lead first. Each
writes its own run log and card (``car-1.csv`` .. ``car-N.csv``); then the platoon's figures
(:func:`energy.string_stability.string_stability`) go to ``platoon.json`` and the screen,
with a time-space diagram and the amplification by position. ``vacc metrics DIR`` prints
the same figures for a platoon folder.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np

from agent_client.cli import parse_faults, parse_hostport
from agent_client.launcher import launch, reap
from agent_client.runlog import read_card
from energy.openacc import METADATA_ROWS, OPENACC_FILES, read_openacc
from energy.runlog import read_run_log
from energy.string_stability import platoon_energy, string_stability
from protocol.constants import MAX_FOLLOWERS
from protocol.scenarios import SCENARIOS, TRAJECTORIES
from sim_server.seats import SEAT_TIMEOUT

__all__ = ["Follower", "parse_followers", "read_platoon", "platoon_figures", "figure_lines", "platoon"]

KINDS = ("acc", "hdm", "ddqn", "human-file")  # controllers that drive a seat unattended
VEHICLE = {"ice": "corolla", "ev": "leaf"}  # each scenario's energy model, as vacc metrics picks


@dataclass(frozen=True)
class Follower:
    """One seat's driver: a controller kind, its file (ddqn's checkpoint, human-file's record) and vehicle."""

    kind: str
    path: str | None
    scenario: str

    def drive_args(self) -> list[str]:
        args = ["--controller", self.kind, "--scenario", self.scenario]
        if self.path is not None:
            args += ["--checkpoint" if self.kind == "ddqn" else "--human-file", self.path]
        return args


def parse_followers(spec: str, scenario: str) -> list[Follower]:
    """``acc,hdm@ev,ddqn:models/ev-eco.pt,...`` -> one :class:`Follower` per seat.

    Raises:
        click.BadParameter: an unknown kind, a file missing or given to a kind that takes
            none, an unknown vehicle, or not 1..16 followers.
    """
    out = []
    for n, item in enumerate(spec.split(","), start=1):
        item = item.strip()
        body, _, vehicle = item.partition("@")
        kind, _, path = body.partition(":")
        where = f"follower {n} ({item!r})"
        if kind not in KINDS:
            raise click.BadParameter(f"{where}: kind {kind!r} is not one of {', '.join(KINDS)}", param_hint="--followers")
        if (kind in ("ddqn", "human-file")) != bool(path):
            need = "needs its file, as ddqn:PATH" if kind in ("ddqn", "human-file") else "takes no file"
            raise click.BadParameter(f"{where}: {kind} {need}", param_hint="--followers")
        if path and not Path(path).is_file():
            raise click.BadParameter(f"{where}: no file {path}", param_hint="--followers")
        if vehicle and vehicle not in SCENARIOS:
            raise click.BadParameter(f"{where}: vehicle {vehicle!r} is not one of {', '.join(SCENARIOS)}", param_hint="--followers")
        out.append(Follower(kind, path or None, vehicle or scenario))
    if not 1 <= len(out) <= MAX_FOLLOWERS:
        raise click.BadParameter(f"a platoon has 1..{MAX_FOLLOWERS} followers, got {len(out)}", param_hint="--followers")
    return out


def _is_openacc(lead: str) -> bool:
    if lead in OPENACC_FILES:
        return True
    try:
        with open(lead, encoding="utf-8") as f:
            return f.readline().startswith(METADATA_ROWS[0] + ",")
    except OSError:
        return False


def lead_args(lead: str, out: Path) -> tuple[list[str], float | None]:
    """The ``vacc drive`` lead options for ``--lead``, and the lead's first speed [m/s] for an
    OpenACC file (whose leader's speed is written to ``out/lead.csv``), else None.

    Raises:
        click.BadParameter: not a trajectory, an OpenACC file or a CSV that exists.
    """
    if lead in TRAJECTORIES:
        return ["--trajectory", lead], None
    if _is_openacc(lead):
        run = read_openacc(lead)
        ok = np.isfinite(run.speed[0])
        t, v = run.t[ok] - run.t[ok][0], run.speed[0, ok]
        path = out / "lead.csv"
        path.write_text("t_s,speed_mps\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), v.tolist(), strict=True)))
        return ["--trajectory", str(path)], float(v[0])
    if not Path(lead).is_file():
        raise click.BadParameter(f"{lead!r} is no trajectory ({', '.join(TRAJECTORIES)}), OpenACC file or CSV trace", param_hint="--lead")
    return ["--trajectory", lead], None


def read_platoon(folder: Path) -> tuple[list[Path], np.ndarray, np.ndarray, np.ndarray, bool]:
    """A platoon folder's car logs (``car-1.csv`` ..), their times [s], speeds [m/s] (the
    lead's first, [cars + 1, N]), gaps [m] ([cars, N]) and whether any car collided.

    Raises:
        click.ClickException: no car logs, or logs that do not share their frames.
        energy.errors.RunLogError: a log that does not read.
    """
    paths = sorted(folder.glob("car-*.csv"), key=lambda p: int(p.stem[4:]) if p.stem[4:].isdigit() else 0)
    if not paths:
        raise click.ClickException(f"{folder}: no car-N.csv logs (a folder written by vacc platoon)")
    logs = [read_run_log(p) for p in paths]
    n = min(len(g.t) for g in logs)
    if n < 3 or any(not np.array_equal(g.frame[:n], logs[0].frame[:n]) for g in logs):
        raise click.ClickException(f"{folder}: the car logs do not share their frames (not one platoon's run)")
    v = np.vstack([logs[0].v_lead[:n], *(g.v_host[:n] for g in logs)])
    gaps = np.vstack([g.gap[:n] for g in logs])
    return paths, logs[0].t[:n], v, gaps, any(bool(g.collision[:n].any()) for g in logs)


def platoon_figures(folder: Path) -> dict[str, Any]:
    """String-stability, safety and energy figures of a platoon folder (:func:`read_platoon`).

    Raises:
        as :func:`read_platoon`.
    """
    paths, t, v, gaps, collided = read_platoon(folder)
    cards = [read_card(p) for p in paths]
    scenarios = [c["episode"]["scenario"] if c else "ice" for c in cards]  # no card: the ICE model, as vacc metrics
    figures = string_stability(t, v, gaps)
    cars = platoon_energy(t, v[1:], [VEHICLE[s] for s in scenarios])
    figures["fuel_total_g"] = sum(c.fuel_g for c in cars)
    figures["energy_total_kj"] = sum(c.energy_kj for c in cars)
    figures["collision"] = float(collided)
    return {"cars": [p.name for p in paths], "scenarios": scenarios, "frames": int(t.size), "figures": figures}


def figure_lines(result: dict[str, Any]) -> list[str]:
    """The figures a person reads first, a line each."""
    f = result["figures"]
    n = len(result["cars"])
    lines = [f"platoon of {n} behind the lead, {result['frames']} frames"]
    lines.append("speed-deviation amplification (RMS, after the first fifth), pair by pair:")
    lines.append("  " + "  ".join(f"{i}->{i + 1} {f[f'amp_{i}_{i + 1}_speed_rms']:.2f}" for i in range(n)))
    lines.append(f"lead to last: speed RMS {f['amp_lead_last_speed_rms']:.2f}, peak {f['amp_lead_last_speed_peak']:.2f}; "
                 f"accel RMS {f['amp_lead_last_accel_rms']:.2f}")  # fmt: skip
    lines.append(f"lead's deviation {f['lead_speed_dev_rms_mps']:.3f} m/s, last car's {f['last_speed_dev_rms_mps']:.3f} m/s")
    gaps = [f[f"min_gap_{i}_m"] for i in range(1, n + 1)]
    ttc = [f[f"min_ttc_{i}_s"] for i in range(1, n + 1)]
    lines.append(f"closest gap {min(gaps):.2f} m (car {int(np.argmin(gaps)) + 1}); shortest time to collision {min(ttc):.1f} s")
    lines.append(f"fuel {f['fuel_total_g']:.1f} g, EV energy {f['energy_total_kj']:.1f} kJ; collision: {'yes' if f['collision'] else 'no'}")
    return lines


def _json_safe(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    return x


def _clients(addr: tuple[str, int], followers: list[Follower], common: list[str], out: Path) -> list[str]:
    """Run one ``vacc drive`` per seat to its end; one line per client that failed."""
    procs = []
    for i, fol in enumerate(followers):
        cmd = [sys.executable, "-m", "vacc", "drive", "--server", f"{addr[0]}:{addr[1]}", "--seat", str(i), *fol.drive_args(), *common,
               "--log", str(out / f"car-{i + 1}.csv"), "--quiet"]  # fmt: skip
        err = open(out / f"car-{i + 1}.stderr", "w")  # noqa: SIM115 - closed below, after the client exits
        procs.append((subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, text=True), err))
    failed = []
    try:
        for i, (p, err) in enumerate(procs):
            rc = p.wait()
            err.close()
            path = out / f"car-{i + 1}.stderr"
            text = path.read_text().strip().splitlines()
            if rc != 0:
                failed.append(f"seat {i} ({followers[i].kind}): {text[-1] if text else f'exit {rc}'}")
            elif not text:
                path.unlink()  # kept only where a client said something
    finally:
        for p, err in procs:  # an interrupt: no client outlives the command
            if p.poll() is None:
                p.terminate()
                p.wait()
            err.close()
    return failed


@click.command("platoon")
@click.option("--lead", default="test-1", show_default=True, metavar="TRAJECTORY|PATH.csv|OPENACC", help=f"What the lead drives: {', '.join(TRAJECTORIES)}, a CSV speed trace t_s,speed_mps, or an OpenACC file (a shipped name such as {OPENACC_FILES[0]}, or a path): its leader's speed.")
@click.option("--followers", "followers_spec", required=True, metavar="KIND,...", help="One driver per seat, nearest the lead first: acc, hdm, ddqn:CHECKPOINT, human-file:PATH; @ice or @ev after one picks its vehicle.")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(SCENARIOS), help="Vehicle of every follower without its own @ice/@ev.")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path), help="Folder for car-N.csv logs and cards, platoon.json and the figures.")
@click.option("--server", default=None, metavar="HOST:PORT", help="Join a running platoon server (vacc serve --followers N); default: spawn one.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode seed: initial conditions, traffic, scenery.")
@click.option("--duration", default=None, type=click.FloatRange(min=0.1), help="Stop after this many simulated seconds.")
@click.option("--gap", default=None, type=float, metavar="M", help="Every follower's initial gap [m]. Default: drawn from the seed (an OpenACC lead: the ACC's reference gap at its first speed).")
@click.option("--faults", default=None, help="Faults on every client's sends, e.g. 'drop=0.2,dup=0.1,reorder=0.1'.")
@click.option("--server-faults", default=None, help="Faults on the spawned server's sends (same syntax).")
@click.option("--seat-timeout", default=SEAT_TIMEOUT, show_default=True, type=click.FloatRange(0.1, 3600), help="Seconds the spawned server waits for a seat's action before it ends every seat, naming it.")
@click.option("--key-file", default=None, type=click.Path(dir_okay=False), help="Shared key: the spawned server and every client seal each datagram.")
@click.option("--no-figures", is_flag=True, help="Write no PNG figures (platoon.json and the table only).")
def platoon(lead: str, followers_spec: str, scenario: str, out: Path, server: str | None, seed: int, duration: float | None, gap: float | None,
            faults: str | None, server_faults: str | None, seat_timeout: float, key_file: str | None, no_figures: bool) -> None:  # fmt: skip
    """Drive a platoon over UDP: a lead and one client process per follower, in lockstep.

    Writes OUT/car-N.csv (car 1 nearest the lead) with their cards, OUT/platoon.json and,
    unless --no-figures, OUT/time_space.png and OUT/amplification.png; prints the platoon's
    string-stability figures. Exits non-zero, naming the seat, if any client failed.
    """
    followers = parse_followers(followers_spec, scenario)
    for name, value in (("--faults", faults), ("--server-faults", server_faults)):
        if value:
            parse_faults(click.get_current_context(), click.Option([name]), value)  # one clear line for a bad spec
    out.mkdir(parents=True, exist_ok=True)
    lead_opts, v0 = lead_args(lead, out)
    common = [*lead_opts, "--seed", str(seed)]
    if v0 is not None:
        from agent_client.controllers.acc import AccController

        common += ["--host-speed", repr(v0)]
        gap = AccController().reference_gap(v0) if gap is None else gap
    if gap is not None:
        common += ["--gap", repr(gap)]
    if duration is not None:
        common += ["--duration", repr(duration)]
    if faults:
        common += ["--faults", faults]
    if key_file:
        common += ["--key-file", key_file]
    started = time.monotonic()
    proc = None
    if server is None:
        args = ["--port", "0", "--followers", str(len(followers)), "--seat-timeout", repr(seat_timeout)]
        proc, addr = launch(*args, *(["--faults", server_faults] if server_faults else []), key_file=key_file)
    else:
        addr = parse_hostport(server)
    try:
        failed = _clients(addr, followers, common, out)
    finally:
        if proc is not None:
            reap(proc)
    if failed:
        raise click.ClickException("platoon failed: " + "; ".join(failed) + f" (logs so far in {out})")
    result = platoon_figures(out)
    result["wall_s"] = round(time.monotonic() - started, 3)
    (out / "platoon.json").write_text(json.dumps(_json_safe(result), indent=2) + "\n")
    if not no_figures:
        _plots(out)
    click.echo("\n".join(figure_lines(result)))
    click.echo(f"wrote {out}/car-1..{len(followers)}.csv, platoon.json{'' if no_figures else ', time_space.png, amplification.png'}")


def _plots(out: Path) -> None:
    from sim_server.scene import CAR_LENGTH
    from vacc.platoon_figures import plot_amplification, plot_time_space, positions

    _, t, v, gaps, _ = read_platoon(out)
    plot_time_space(out, t, positions(t, v[0], gaps, CAR_LENGTH), v)
    plot_amplification(out, t, v)
