"""`vacc bench`: speed figures, each measured beside its peer in the same run.

The machine is shared and noisy, so absolute times mean little: each figure is the
median of several repetitions after a warm-up, with its spread, next to a peer
measured moments before (a raw UDP echo for the lockstep round trip).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import click
import numpy as np

from agent_client.launcher import local_server
from agent_client.progress import progress_bar
from agent_client.session import Session
from vacc.host import cpu_model
from vacc.paths import models_dir

ECHO_SERVER = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, addr = s.recvfrom(70000)
    if data == b"quit":
        break
    s.sendto(data, addr)
"""


def _summary(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples)
    return {"median": float(np.median(a)), "p99": float(np.percentile(a, 99)), "min": float(a.min()), "max": float(a.max())}


def _reps(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "reps": len(values)}


def udp_echo(steps: int, reps: int, payload: int = 64) -> dict[str, Any]:
    """Round trips/s and RTT of a bare Python UDP echo process on loopback."""
    proc = subprocess.Popen([sys.executable, "-c", ECHO_SERVER], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect(("127.0.0.1", port))
        data = b"x" * payload
        rates, rtts = [], []
        for rep in range(reps + 1):
            t0 = time.perf_counter()
            for _ in range(steps):
                t = time.perf_counter()
                sock.send(data)
                sock.recv(70000)
                rtts.append(time.perf_counter() - t)
            if rep:  # the first repetition is the warm-up
                rates.append(steps / (time.perf_counter() - t0))
        sock.send(b"quit")
        sock.close()
    finally:
        proc.wait(timeout=5)
        if proc.stdout is not None:
            proc.stdout.close()
    return {"steps_per_s": _reps(rates), "rtt_us": {k: v * 1e6 for k, v in _summary(rtts[steps:]).items()}}


def lockstep(steps: int, reps: int, image_format: str = "none", size: tuple[int, int] = (400, 400)) -> dict[str, Any]:
    """Lockstep steps/s and per-step round trip with a real server process."""
    rates, rtts = [], []
    with local_server() as addr, Session(addr, image_format=image_format, image_size=size) as s:
        for rep in range(reps + 1):
            s.reset(seed=rep, trajectory="random")
            t0 = time.perf_counter()
            for _ in range(steps):
                t = time.perf_counter()
                obs = s.step(0.0)
                rtts.append(time.perf_counter() - t)
                if obs["truncated"] or obs["terminated"]:
                    s.reset(seed=rep + 100, trajectory="random")
            if rep:
                rates.append(steps / (time.perf_counter() - t0))
        nbytes = len(obs["image"]) if obs["image"] is not None else 0
    return {"steps_per_s": _reps(rates), "rtt_us": {k: v * 1e6 for k, v in _summary(rtts[steps:]).items()}, "image_bytes": nbytes}


def lockstep_key(steps: int, reps: int) -> dict[str, Any]:
    """Cost of a shared key (a MAC and a replay check on every datagram): lockstep
    steps/s with and without ``--key-file``, repetitions interleaved in one run."""
    import tempfile

    from protocol.auth import load_key

    rates: dict[str, list[float]] = {"plain": [], "keyed": []}
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        key_file = Path(tmp) / "bench.key"
        key_file.write_bytes(os.urandom(32).hex().encode())
        sessions = {
            "plain": stack.enter_context(Session(stack.enter_context(local_server()))),
            "keyed": stack.enter_context(Session(stack.enter_context(local_server(key_file=key_file)), key=load_key(key_file))),
        }
        for rep in range(reps + 1):
            for name, s in sessions.items():
                s.reset(seed=rep, trajectory="random")
                t0 = time.perf_counter()
                for _ in range(steps):
                    obs = s.step(0.0)
                    if obs["truncated"] or obs["terminated"]:
                        s.reset(seed=rep + 100, trajectory="random")
                if rep:  # the first repetition is the warm-up
                    rates[name].append(steps / (time.perf_counter() - t0))
    plain, keyed = statistics.median(rates["plain"]), statistics.median(rates["keyed"])
    return {"plain": _reps(rates["plain"]), "keyed": _reps(rates["keyed"]), "ratio": keyed / plain}


def _seat_client(addr: tuple[str, int], seat: int, steps: int, episodes: int, out: Any) -> None:
    """One seat's client in its own process: ``episodes`` platoon episodes of ``steps``
    frames, a gap-keeping law; puts (frames, start, end) [s, monotonic] of each episode."""
    with Session(addr, seat=seat, client_name="vacc-bench-seat") as s:
        for ep in range(episodes):
            obs = s.reset(seed=ep, trajectory="test-1", duration=steps * float(s.welcome["control_period"]))  # type: ignore[index]
            t0 = time.monotonic()
            while not (obs["terminated"] or obs["truncated"]):  # the episode's end: no seat leaves one running
                u = 0.02 * (obs["gap"] - 40.0) + 0.2 * (obs["v_lead"] - obs["v_host"])
                obs = s.step(max(-1.0, min(1.0, u)))
            out.put((obs["frame"], t0, time.monotonic()))


def platoon_lockstep(steps: int, reps: int, followers: int = 10) -> dict[str, Any]:
    """Lockstep frames/s, and steps/s per simulated car, of a platoon server with
    ``followers`` seats and with one, each seat's client its own process, no images;
    repetitions interleaved in one run (the first a warm-up)."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    per_car: dict[int, list[float]] = {1: [], followers: []}
    with contextlib.ExitStack() as stack:
        servers = {n: stack.enter_context(local_server("--followers", str(n))) for n in per_car}
        for rep in range(reps + 1):
            for n, addr in servers.items():
                out = ctx.Queue()
                procs = [ctx.Process(target=_seat_client, args=(addr, i, steps, 1, out), daemon=True) for i in range(n)]
                for p in procs:
                    p.start()
                spans = [out.get(timeout=120) for _ in procs]
                for p in procs:
                    p.join(30)
                if rep:
                    frames_per_s = spans[0][0] / (max(e for _, _, e in spans) - min(t for _, t, _ in spans))
                    per_car[n].append(frames_per_s * n)
    one, many = statistics.median(per_car[1]), statistics.median(per_car[followers])
    return {"followers": followers, "one": _reps(per_car[1]), "many": _reps(per_car[followers]), "ratio": many / one}


def reset_flood(host: str, port: int, sockets: int, seconds: float) -> None:
    """Send valid maximum-size resets (two full float-64 traces, 2.36 MB, a stranger's
    token) from ``sockets`` sockets in turn for ``seconds``: the decode-budget attack.
    Run in its own process (``python -c``) so that it does not share the caller's GIL."""
    from protocol import codec
    from protocol.fragment import fragment

    n = codec.MAX_ARRAY_LEN
    reset = {"type": "reset", "session": bytes(16), "episode": 0, "scenario": "ice", "seed": 0, "trajectory": "trace",
             "trace_t": [float(i) for i in range(n)], "trace_v": [10.0] * n, "duration": None, "host_speed": None,
             "gap": None, "set_speed": None, "preroll": None}  # fmt: skip
    datagrams = fragment(codec.encode(reset), 1)
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(sockets)]
    deadline, msg_id = time.monotonic() + seconds, 1
    try:
        while time.monotonic() < deadline:  # bounded in time; each round is one message a socket
            msg_id += 1
            for sock in socks:
                for d in datagrams:
                    try:
                        sock.sendto(d[:4] + (msg_id & 0xFFFFFFFF).to_bytes(4, "big") + d[8:], (host, port))
                    except OSError:
                        pass  # a full buffer: the kernel drops, as it would on a real flood
    finally:
        for sock in socks:
            sock.close()


def flood_rtt(samples: int = 300, sockets: int = 16, addr: tuple[str, int] | None = None) -> dict[str, Any]:
    """A live session's heartbeat round trip idle and while ``sockets`` sockets flood the
    server with valid maximum-size resets (its peer is itself, idle, in the same run)."""

    def rtts(s: Session) -> list[float]:
        out = []
        for _ in range(samples):
            t = time.perf_counter()
            s.heartbeat()
            out.append(time.perf_counter() - t)
            time.sleep(0.002)
        return out

    with contextlib.ExitStack() as stack:
        addr = addr or stack.enter_context(local_server(stderr=subprocess.DEVNULL))
        s = stack.enter_context(Session(addr))
        s.reset(seed=0)
        rtts(s)  # warm-up
        idle = rtts(s)
        seconds = 3.0 + samples * 0.004
        code = f"from vacc.bench import reset_flood; reset_flood({addr[0]!r}, {addr[1]}, {sockets}, {seconds})"
        flood = subprocess.Popen([sys.executable, "-c", code])
        try:
            time.sleep(1.0)  # let the flood fill the server's queue
            loaded = rtts(s)
        finally:
            flood.kill()
            flood.wait(timeout=10)
    i, f = _summary(idle), _summary(loaded)
    return {"idle_ms": {k: v * 1e3 for k, v in i.items()}, "flood_ms": {k: v * 1e3 for k, v in f.items()}, "sockets": sockets, "ratio": f["median"] / i["median"]}


def _env_rate(env: Any, action: int, steps: int, reps: int) -> dict[str, Any]:
    """Steps/s of a Gymnasium env over ``reps`` timed repetitions after a warm-up one."""
    rates = []
    try:
        env.reset(seed=0)
        for rep in range(reps + 1):
            t0 = time.perf_counter()
            for _ in range(steps):
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            if rep:
                rates.append(steps / (time.perf_counter() - t0))
    finally:
        env.close()
    return {"steps_per_s": _reps(rates)}


def agent_env(steps: int, reps: int) -> dict[str, Any]:
    """Steps/s of the Gymnasium env as the agent uses it: gray 200x200 camera over
    UDP from a real server process, preprocessing and the 8-frame stack."""
    from agent_client.env import VisionACCEnv

    return _env_rate(VisionACCEnv(trajectory="random"), 10, steps, reps)  # action 10: u = 0


HIGHWAY_CONFIG = {
    "observation": {
        "type": "GrayscaleObservation",
        "observation_shape": (150, 105),
        "stack_size": 8,
        "weights": [0.2989, 0.5870, 0.1140],
        "scaling": 1.75,
    },
    "simulation_frequency": 50,  # [Hz] as our physics
    "policy_frequency": 50,  # [Hz] one decision per simulation step
    "offscreen_rendering": True,
}


def highway_peer(steps: int, reps: int) -> dict[str, Any]:
    """Steps/s of highway-env's highway-v0 with an 8x150x105 grayscale stack at 50 Hz, in-process."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401 - registers highway-v0
    except ImportError:
        return {"error": "highway-env is not installed: pip install 'vacc[bench]' (make bench does)"}
    return _env_rate(gym.make("highway-v0", config=HIGHWAY_CONFIG), 1, steps, reps)  # action 1: IDLE


def _render_scenes(seed: int, n: int) -> list:
    """``n`` consecutive camera states of a world run (ice scenario, 0.1 s apart)."""
    from sim_server.world import World

    world = World()
    world.reset("ice", seed, "test-1")
    scenes = []
    for _ in range(n):
        world.step(0.1)
        scenes.append(world.scene())
    return scenes


def render_time(frames: int, size: tuple[int, int] = (400, 400), gray: bool = False) -> dict[str, Any]:
    """Median and p99 time to render one RGB frame in this process (one core).

    ``gray`` adds the server's conversion to gray, as the agent asks for it.
    """
    import cv2

    from sim_server.render import CameraConfig, Renderer

    cv2.setNumThreads(1)
    renderer = Renderer(CameraConfig(width=size[0], height=size[1]))
    scenes = _render_scenes(0, 64)
    for scene in scenes + scenes:  # warm-up: fills the background caches
        renderer.render(scene)
    times = []
    for i in range(frames):
        t = time.perf_counter()
        img = renderer.render(scenes[i % len(scenes)])
        if gray:
            cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        times.append(time.perf_counter() - t)
    return {"ms": {k: v * 1e3 for k, v in _summary(times).items()}}


def render_new_seed(seeds: int, size: tuple[int, int] = (400, 400), frames: int = 50) -> dict[str, Any]:
    """Cost of a new scenery seed, as every training episode has: the first frame, and
    the first ``frames`` frames together, on a renderer already warmed with another seed."""
    import cv2

    from sim_server.render import CameraConfig, Renderer

    cv2.setNumThreads(1)
    renderer = Renderer(CameraConfig(width=size[0], height=size[1]))
    for scene in _render_scenes(0, 130):  # warm-up: one seed over all dash phases
        renderer.render(scene)
    first, total = [], []
    for k in range(seeds):
        scenes = _render_scenes(1000 + k, frames)
        t0 = time.perf_counter()
        renderer.render(scenes[0])
        first.append(time.perf_counter() - t0)
        for scene in scenes[1:]:
            renderer.render(scene)
        total.append(time.perf_counter() - t0)
    return {"first_ms": {k: v * 1e3 for k, v in _summary(first).items()},
            "frames": frames, "total_ms": {k: v * 1e3 for k, v in _summary(total).items()}}


def _tree_rss(pid: int) -> dict[int, int]:
    """RSS [bytes] of a process and all its descendants, from /proc."""
    out: dict[int, int] = {}
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    out[p] = int(line.split()[1]) * 1024
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
    return out


ECO_MODEL = "ice-eco.pt"  # the shipped model whose whole decision (zoom 2, controls, the mean) the bench times too
GRU_STACK = 2  # frames the recurrent trunk's row stacks (its GRU carries the rest)


def training_peak_rss(steps: int) -> dict[str, Any]:
    """Peak RSS of the trainer and of its simulator server during a `vacc train` run."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable, "-m", "vacc", "train", "--reward", "gap", "--steps", str(steps), "--out", tmp,
            "--learning-starts", str(min(5000, steps // 4)), "--eval-every", "0", "--eval-trajectories", "test-1",
            "--eval-seconds", "5", "--checkpoint-every", str(max(1000, steps // 5)), "--quiet",
        ]  # fmt: skip
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        peak_trainer = peak_servers = 0
        t0 = time.perf_counter()
        while proc.poll() is None:
            rss = _tree_rss(proc.pid)
            peak_trainer = max(peak_trainer, rss.pop(proc.pid, 0))
            peak_servers = max(peak_servers, max(rss.values(), default=0))
            time.sleep(0.2)
        wall = time.perf_counter() - t0
    if proc.returncode != 0:
        return {"error": f"vacc train exited {proc.returncode}"}
    return {"steps": steps, "wall_s": wall, "trainer_peak_rss_mb": peak_trainer / 1e6, "server_peak_rss_mb": peak_servers / 1e6}


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("numpy", "torch", "opencv-python-headless", "pymunk", "msgpack", "gymnasium"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


class Sizes(NamedTuple):
    """How much each part of the bench measures: its steps, repetitions and sample counts."""

    name: str
    steps: int  # lockstep and echo steps per repetition
    reps: int
    renders: int
    new_seeds: int
    decisions: int
    replay_capacity: int
    updates: int
    train_steps: int
    learning_starts: int
    rss_steps: int
    flood_samples: int  # heartbeats timed idle and under the reset flood
    platoon: int = 10  # seats of the platoon row, each its own client process


SIZES = {
    "full": Sizes("full", 3000, 5, 2000, 20, 2000, 100_000, 30, 6000, 1000, 50_000, 400),
    "quick": Sizes("quick", 500, 3, 500, 5, 300, 20_000, 10, 600, 200, 1500, 100),
    # every row once, as small as it runs: the tests' check that each figure is made (its numbers mean little)
    "smoke": Sizes("smoke", 100, 1, 50, 2, 100, 2_000, 2, 120, 40, 200, 50, platoon=3),
}


def actor_critic_rows(z: Sizes) -> dict[str, Any]:
    """The actor-critic (DrQ-v2, the continuous action) beside SB3's SAC on the same env and
    trunk: training steps/s, each in its own run of the same steps, and the decision latency
    beside SAC's ``predict``; each ratio where the peer ran."""
    from agent_client.bench import ddqn as ddqn_bench
    from agent_client.rl.config import Config
    from vacc import bench_sb3

    lat = ddqn_bench.decision_latency(repeats=z.decisions, cfg=Config(action="continuous"))
    rows: dict[str, Any] = {
        "drqv2_training": ddqn_bench.training_rate(z.train_steps, z.learning_starts, schedule="serial", action="continuous"),
        "sb3_sac_peer": bench_sb3.sb3_training_rate_isolated(z.train_steps, z.learning_starts, algo="sac"),
        "actor_decision_latency": {"ms": {"median": lat["median_s"] * 1e3, "p90": lat["p90_s"] * 1e3}, "forward_ms": lat["forward_median_s"] * 1e3},
    }
    peer = bench_sb3.sb3_sac_decision_latency(repeats=z.decisions)
    rows["sb3_sac_decision_peer"] = peer if "error" in peer else {"ms": {"median": peer["median_s"] * 1e3, "p90": peer["p90_s"] * 1e3}}
    if "error" not in rows["sb3_sac_peer"]:
        rows["drqv2_training"]["x_sb3"] = rows["drqv2_training"]["steps_per_s_overall"] / rows["sb3_sac_peer"]["steps_per_s_overall"]
    if "error" not in rows["sb3_sac_decision_peer"]:
        rows["actor_decision_latency"]["fraction_of_sb3"] = lat["median_s"] * 1e3 / rows["sb3_sac_decision_peer"]["ms"]["median"]
    return rows


def _actor_critic_lines(f: dict[str, Any]) -> list[str]:
    """The table's lines of :func:`actor_critic_rows` (none for a bench written before them)."""
    if "drqv2_training" not in f:
        return []
    t, x = f["drqv2_training"], f["drqv2_training"].get("x_sb3")
    lines = [f"{'DrQ-v2 training (continuous)':34} {t['steps_per_s_overall']:>9.1f} /s {'':>22}  >= 1.5x SB3 SAC" + (f" ({x:.2f}x)" if x else "")]
    peer = f["sb3_sac_peer"]
    lines.append(f"{'SB3 SAC, same trunk and env (peer)':34} " + (peer["error"] if "error" in peer else f"{peer['steps_per_s_overall']:>9.1f} /s  (own process, {peer.get('threads', 1)} threads)"))
    d, frac = f["actor_decision_latency"]["ms"], f["actor_decision_latency"].get("fraction_of_sb3")
    lines.append(f"{'actor decision latency (1 thread)':34} {d['median']:>9.3f} ms {'p90 ' + format(d['p90'], '.3f'):>22}  <= 0.5x SB3 SAC" + (f" ({frac:.2f}x)" if frac else ""))
    peer = f["sb3_sac_decision_peer"]
    lines.append(f"{'SB3 SAC predict, same trunk':34} " + (peer["error"] if "error" in peer else f"{peer['ms']['median']:>9.3f} ms {'p90 ' + format(peer['ms']['p90'], '.3f'):>22}  (peer)"))
    return lines


def run_bench(size: str) -> dict[str, Any]:
    """Every figure of the bench at ``size``: a key of :data:`SIZES`."""
    z = SIZES[size]
    steps, reps = z.steps, z.reps
    rows: dict[str, Any] = {}
    with progress_bar(12, "bench", unit="part") as bar:
        rows["udp_echo"] = udp_echo(steps, reps)
        bar.update(1)
        rows["lockstep_no_image"] = lockstep(steps, reps)
        bar.update(1)
        rows["lockstep_rgb400"] = lockstep(max(50, steps // 10), reps, "rgb", (400, 400))
        bar.update(1)
        rows["lockstep_gray200"] = lockstep(max(100, steps // 5), reps, "gray", (200, 200))
        rows["lockstep_key"] = lockstep_key(steps, reps)
        rows["flood_rtt"] = flood_rtt(z.flood_samples)
        rows["platoon_lockstep"] = platoon_lockstep(min(steps, 2000), reps, z.platoon)
        bar.update(1)
        rows["render_rgb400"] = render_time(z.renders)
        rows["render_gray200"] = render_time(z.renders, (200, 200), gray=True)
        rows["render_new_seed"] = render_new_seed(z.new_seeds)
        bar.update(1)
        rows["agent_env"] = agent_env(max(100, steps // 5), reps)
        bar.update(1)
        rows["highway_env_peer"] = highway_peer(max(50, steps // 20), reps)
        bar.update(1)
        from agent_client.bench import ddqn as ddqn_bench
        from agent_client.rl.config import Config
        from vacc import bench_sb3

        lat = ddqn_bench.decision_latency(repeats=z.decisions)
        rows["decision_latency"] = {"ms": {"median": lat["median_s"] * 1e3, "p90": lat["p90_s"] * 1e3}, "forward_ms": lat["forward_median_s"] * 1e3}
        gru = ddqn_bench.decision_latency(repeats=z.decisions, cfg=Config(recurrent="gru", frame_stack=GRU_STACK, stack_stride=2))
        rows["gru_decision_latency"] = {"ms": {"median": gru["median_s"] * 1e3, "p90": gru["p90_s"] * 1e3}, "forward_ms": gru["forward_median_s"] * 1e3,
                                        "x_stack": gru["median_s"] / lat["median_s"]}  # fmt: skip
        eco = ddqn_bench.model_decision_latency(models_dir() / ECO_MODEL, repeats=z.decisions)
        rows["eco_decision_latency"] = eco if "error" in eco else {
            "model": eco["model"], "ms": {"median": eco["median_s"] * 1e3, "p90": eco["p90_s"] * 1e3}, "forward_ms": eco["forward_median_s"] * 1e3}
        peer_lat = bench_sb3.sb3_decision_latency(repeats=z.decisions)
        rows["sb3_decision_peer"] = peer_lat if "error" in peer_lat else {"ms": {"median": peer_lat["median_s"] * 1e3, "p90": peer_lat["p90_s"] * 1e3}}
        sample = ddqn_bench.sample_latency(capacity=z.replay_capacity)
        rows["replay_sample"] = {"ms": {"median": sample["median_s"] * 1e3, "p90": sample["p90_s"] * 1e3}, "capacity": sample["capacity"]}
        rows["update_cost"] = {"ms": ddqn_bench.update_cost(z.updates)["median_s"] * 1e3}
        bar.update(1)
        train_steps, starts = z.train_steps, z.learning_starts
        rows["ddqn_training"] = ddqn_bench.training_rate(train_steps, starts, schedule="serial")
        rows["ddqn_training_parallel"] = ddqn_bench.training_rate(train_steps, starts, schedule="parallel")
        bar.update(1)
        rows["sb3_dqn_peer"] = bench_sb3.sb3_training_rate_isolated(train_steps, starts)
        rows.update(actor_critic_rows(z))
        bar.update(1)
        rows["replay"] = ddqn_bench.replay_bytes_per_transition()
        rows["sb3_replay_peer"] = bench_sb3.sb3_replay_bytes()
        rows["training_peak_rss"] = training_peak_rss(z.rss_steps)
        bar.update(1)
    if "error" not in rows["sb3_dqn_peer"]:
        for name in ("ddqn_training", "ddqn_training_parallel"):
            rows[name]["x_sb3"] = rows[name]["steps_per_s_overall"] / rows["sb3_dqn_peer"]["steps_per_s_overall"]
    if "error" not in rows["sb3_decision_peer"]:
        rows["decision_latency"]["fraction_of_sb3"] = rows["decision_latency"]["ms"]["median"] / rows["sb3_decision_peer"]["ms"]["median"]
    if "error" not in rows["sb3_replay_peer"]:
        rows["replay"]["fraction_of_sb3"] = rows["replay"]["bytes_per_transition"] / rows["sb3_replay_peer"]["bytes_per_transition"]
    if "error" not in rows["highway_env_peer"]:
        peer = rows["highway_env_peer"]["steps_per_s"]["median"]
        rows["agent_env"]["x_highway_env"] = rows["agent_env"]["steps_per_s"]["median"] / peer
    echo = rows["udp_echo"]["steps_per_s"]["median"]
    rows["lockstep_no_image"]["pct_of_echo"] = 100.0 * rows["lockstep_no_image"]["steps_per_s"]["median"] / echo
    return {
        "header": {
            "date": time.strftime("%Y-%m-%d %H:%M:%S"),
            "cpu": cpu_model(),
            "cores": os.cpu_count(),
            "quick": z.name != "full",
            "size": z.name,
            "versions": _versions(),
        },
        "figures": rows,
    }


def _session_lines(f: dict[str, Any]) -> list[str]:
    """The table's lines of the keyed, flooded and platoon sessions (a bench before a row has none of it)."""
    k = f["lockstep_key"]
    cost = 1e6 * (1 / k["keyed"]["median"] - 1 / k["plain"]["median"])  # [us] per step
    lines = [f"{'lockstep with --key-file':34} {k['keyed']['median']:>9.0f} /s {k['ratio']:>21.2f}x  vs {k['plain']['median']:.0f}/s without key: {cost:+.0f} us a step (>= 0.85x)"]
    fl = f.get("flood_rtt")
    if fl is not None:
        label = f"heartbeat, {fl['sockets']}-socket reset flood"
        lines.append(f"{label:34} {fl['flood_ms']['median']:>9.3f} ms {fl['ratio']:>21.2f}x  vs {fl['idle_ms']['median']:.3f} ms idle (<= 2x); p99 {fl['flood_ms']['p99']:.1f} ms")
    pl = f.get("platoon_lockstep")
    if pl is not None:
        label = f"platoon of {pl['followers']}, no image, per car"
        lines.append(f"{label:34} {pl['many']['median']:>9.0f} /s {pl['ratio']:>21.2f}x  vs {pl['one']['median']:.0f}/s with one follower (>= 0.6x)")
    return lines


def format_table(result: dict[str, Any]) -> str:
    f = result["figures"]
    h = result["header"]
    lines = [
        f"vacc bench  {h['date']}  {h['cpu']} x{h['cores']}  {h.get('size', 'quick' if h['quick'] else 'full')}",
        "  " + ", ".join(f"{k} {v}" for k, v in h["versions"].items()),
        "",
        f"{'figure':34} {'median':>12} {'min..max / p99':>22}  goal",
    ]

    def rate(name: str, label: str, goal: str) -> None:
        r = f[name]["steps_per_s"]
        lines.append(f"{label:34} {r['median']:>9.0f} /s {r['min']:>10.0f}..{r['max']:<10.0f}  {goal}")
        t = f[name]["rtt_us"]
        lines.append(f"{'  round trip':34} {t['median']:>9.1f} us {'p99 ' + format(t['p99'], '.1f'):>22}")

    rate("udp_echo", "raw UDP echo (peer)", "physical limit")
    rate("lockstep_no_image", "lockstep, no image", f">= 5000/s ({f['lockstep_no_image']['pct_of_echo']:.0f}% of echo)")
    rate("lockstep_rgb400", "lockstep, 400x400 RGB (480 KB)", "")
    rate("lockstep_gray200", "lockstep, 200x200 gray (agent)", ">= 1000/s")
    lines += _session_lines(f)
    r = f["agent_env"]["steps_per_s"]
    ratio = f["agent_env"].get("x_highway_env")
    lines.append(f"{'agent env (camera, preprocess, stack)':34} {r['median']:>9.0f} /s {r['min']:>10.0f}..{r['max']:<10.0f}  >= 2x peer" + (f" ({ratio:.1f}x)" if ratio else ""))
    peer = f["highway_env_peer"]
    if "error" in peer:
        lines.append(f"{'highway-env highway-v0 (peer)':34} {peer['error']}")
    else:
        r = peer["steps_per_s"]
        lines.append(f"{'highway-env highway-v0 (peer)':34} {r['median']:>9.0f} /s {r['min']:>10.0f}..{r['max']:<10.0f}  8x150x105 gray, 50 Hz")
    d = f["decision_latency"]["ms"]
    frac = f["decision_latency"].get("fraction_of_sb3")
    lines.append(f"{'decision latency (1 thread)':34} {d['median']:>9.3f} ms {'p90 ' + format(d['p90'], '.3f'):>22}  <= 0.5 ms (paper 3.58 ms GPU)" + (f" ({frac:.2f}x SB3)" if frac else ""))
    lines.append(f"{'  of which the forward alone':34} {f['decision_latency']['forward_ms']:>9.3f} ms {'':>22}  batch 1, the same stack")
    eco = f.get("eco_decision_latency")  # absent from the figures of a bench before it
    if eco is not None:
        label = f"the shipped {eco.get('model', ECO_MODEL)}"
        lines.append(f"{label:34} " + (eco["error"] if "error" in eco else
                     f"{eco['ms']['median']:>9.3f} ms {'p90 ' + format(eco['ms']['p90'], '.3f'):>22}  <= 0.5 ms (forward {eco['forward_ms']:.3f} ms)"))
    gru = f.get("gru_decision_latency")  # absent from a bench before the recurrent trunk
    if gru is not None:
        d = gru["ms"]
        lines.append(f"{'GRU trunk, ' + str(GRU_STACK) + '-frame stack':34} {d['median']:>9.3f} ms {'p90 ' + format(d['p90'], '.3f'):>22}  "
                     f"{gru['x_stack']:.2f}x the 8-frame stack (forward {gru['forward_ms']:.3f} ms)")  # fmt: skip
    peer = f["sb3_decision_peer"]
    lines.append(f"{'SB3 predict, same net, stack given':34} " + (peer["error"] if "error" in peer else f"{peer['ms']['median']:>9.3f} ms {'p90 ' + format(peer['ms']['p90'], '.3f'):>22}  (peer)"))
    d = f["replay_sample"]["ms"]
    lines.append(f"{'replay sample, 32 x 5-step returns':34} {d['median']:>9.3f} ms {'p90 ' + format(d['p90'], '.3f'):>22}  <= 1 ms ({f['replay_sample']['capacity']} full)")
    lines.append(f"{'batch-32 update (1 thread, CPU time)':34} {f['update_cost']['ms']:>9.1f} ms")
    for name, label in (("ddqn_training", "DDQN training, serial (default)"), ("ddqn_training_parallel", "DDQN training, --schedule parallel")):
        t = f[name]
        x = t.get("x_sb3")
        lines.append(f"{label:34} {t['steps_per_s_overall']:>9.1f} /s {'':>22}  >= 1.5x SB3" + (f" ({x:.2f}x)" if x else ""))
    peer = f["sb3_dqn_peer"]
    lines.append(f"{'SB3 DQN, same net and env (peer)':34} " + (peer["error"] if "error" in peer else f"{peer['steps_per_s_overall']:>9.1f} /s  (own process, {peer.get('threads', 1)} threads)"))
    lines += _actor_critic_lines(f)
    if "to_target" in f:
        r = f["to_target"]
        lines.append(f"{'ice-gap from scratch to target':34} {r['wall_s'] / 60:>9.1f} min {'at step ' + str(r['step']):>21}  <= 30 min" + ("" if r["reached"] else " (NOT reached)"))
    r = f["replay"]
    frac = r.get("fraction_of_sb3")
    lines.append(f"{'replay bytes per transition':34} {r['bytes_per_transition']:>9.0f} B  {'':>21}  <= 1/5 of SB3" + (f" (1/{1 / frac:.1f})" if frac else ""))
    peer = f["sb3_replay_peer"]
    lines.append(f"{'SB3 DictReplayBuffer (peer)':34} " + (peer["error"] if "error" in peer else f"{peer['bytes_per_transition']:>9.0f} B"))
    m = f["training_peak_rss"]
    if "error" in m:
        lines.append(f"{'peak RSS during training':34} {m['error']}")
    else:
        lines.append(f"{'peak RSS, ' + str(m['steps']) + '-step training':34} trainer {m['trainer_peak_rss_mb']:.0f} MB, server {m['server_peak_rss_mb']:.0f} MB")
    r = f["render_rgb400"]["ms"]
    lines.append(f"{'render 400x400 RGB':34} {r['median']:>9.3f} ms {'p99 ' + format(r['p99'], '.3f'):>22}  <= 0.5 ms (max 1 ms)")
    r = f["render_gray200"]["ms"]
    lines.append(f"{'render 200x200 gray (agent)':34} {r['median']:>9.3f} ms {'p99 ' + format(r['p99'], '.3f'):>22}")
    r = f["render_new_seed"]
    lines.append(f"{'render, new seed: first frame':34} {r['first_ms']['median']:>9.3f} ms {'max ' + format(r['first_ms']['max'], '.3f'):>22}  a few ms")
    lines.append(f"{'  first ' + str(r['frames']) + ' frames together':34} {r['total_ms']['median']:>9.1f} ms {'max ' + format(r['total_ms']['max'], '.1f'):>22}")
    return "\n".join(lines)


@click.command("bench")
@click.option("--json", "json_path", default=None, type=click.Path(dir_okay=False), help="Also write the figures as JSON.")
@click.option("--quick", is_flag=True, help="Fewer repetitions (under 2 minutes).")
@click.option("--smoke", is_flag=True, help="Every row once at its smallest: checks that each figure is made; its numbers mean little.")
@click.option("--long", "long_", is_flag=True, help="Also train ice-gap from scratch to its target (<= 3.4 m on each test trajectory) and time it (about 30-40 min).")
def bench(json_path: str | None, quick: bool, smoke: bool, long_: bool) -> None:
    """Measure lockstep, rendering, the learner and its peers side by side."""
    if quick and smoke:
        raise click.UsageError("--quick and --smoke are two sizes: give one")
    result = run_bench("smoke" if smoke else "quick" if quick else "full")
    if long_:
        import tempfile

        from agent_client.bench import ddqn as ddqn_bench

        with tempfile.TemporaryDirectory(prefix="vacc-to-target-") as tmp:
            result["figures"]["to_target"] = ddqn_bench.wall_clock_to_target(tmp)
    click.echo(format_table(result))
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps(result, indent=2))
        click.echo(f"wrote {json_path}")
