"""Real server and client processes over 127.0.0.1."""

from __future__ import annotations

import csv
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from lossy_runs import LOSSY_SECONDS, assert_prefix_of
from proctools import job

from agent_client.errors import FatalSessionError, SessionError
from agent_client.launcher import READY_PREFIX, local_server
from agent_client.runlog import COLUMNS
from agent_client.session import Session


def test_acc_drives_test_1_for_four_minutes_without_collision(clean_log, run_vacc):
    path, result = clean_log
    rows = list(csv.DictReader(path.open()))
    assert tuple(rows[0]) == COLUMNS
    assert len(rows) == 2401
    assert float(rows[-1]["t"]) == pytest.approx(240.0)
    assert all(r["collision"] == "0" for r in rows)
    assert min(float(r["gap"]) for r in rows) > 10.0
    assert "collision        no" in result.stdout


def test_same_seed_gives_identical_logs(clean_log, tmp_path, run_vacc):
    path, _ = clean_log
    again = tmp_path / "again.csv"
    assert run_vacc("drive", "--controller", "acc", "--seed", "0", "--log", str(again), "--quiet").returncode == 0
    assert again.read_bytes() == path.read_bytes()
    other = tmp_path / "other.csv"
    assert run_vacc("drive", "--controller", "acc", "--seed", "1", "--log", str(other), "--quiet").returncode == 0
    assert other.read_bytes() != path.read_bytes()


def test_packet_loss_duplication_and_reordering_give_identical_log(clean_log, tmp_path, run_vacc):
    path, _ = clean_log
    lossy = tmp_path / "lossy.csv"
    faults = "drop=0.1,dup=0.05,reorder=0.05"
    result = run_vacc(
        "drive", "--controller", "acc", "--seed", "0", "--log", str(lossy), "--duration", str(LOSSY_SECONDS),
        "--faults", faults + ",seed=11", "--server-faults", faults + ",seed=12",
        env=dict(os.environ, VACC_SERVER_LOG_LEVEL="info"),  # the spawned server's stats line
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    resent = int(result.stdout.split("re-sent requests")[1].split()[0])
    assert resent > 50  # the faults really happened (over 200 in the whole 240 s)
    assert "cached_replies=" in result.stderr  # and the server answered repeats from its cache
    assert len(lossy.read_text().splitlines()) == 1 + round(LOSSY_SECONDS / 0.1) + 1  # header, frames 0..300
    assert_prefix_of(lossy, path)


def test_killed_server_makes_client_exit_nonzero_naming_address(tmp_path):
    log = tmp_path / "k.csv"
    server = [sys.executable, "-m", "sim_server", "--port", "0", "--realtime"]
    with job(server, stdout=subprocess.PIPE) as proc:
        line = proc.stdout.readline()
        assert line.startswith(READY_PREFIX)
        address = line[len(READY_PREFIX) :].strip()
        drive = [sys.executable, "-m", "vacc", "drive", "--controller", "acc", "--server", address, "--give-up", "2", "--log", str(log)]
        with job(drive, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as client:
            deadline = time.monotonic() + 60
            # Realtime: wait until the run is under way, far from its 240 s end.
            while time.monotonic() < deadline and (not log.exists() or len(log.read_text().splitlines()) < 10):
                time.sleep(0.1)
            assert client.poll() is None
            proc.kill()
            killed = time.monotonic()
            _, err = client.communicate(timeout=30)
            elapsed = time.monotonic() - killed
    assert client.returncode != 0
    assert address in err and "last frame" in err
    assert elapsed < 2.0 + 3.0  # give-up time plus process exit
    rows = log.read_text().splitlines()
    assert len(rows) > 5  # the log so far is kept


def test_session_timeout_frees_world_for_a_new_client():
    with local_server("--session-timeout", "0.5") as addr:
        ghost = Session(addr)
        ghost.open()
        ghost.reset(seed=1)
        ghost.endpoint.close()  # vanishes without a close message
        # A second client is refused while the ghost's session is fresh ...
        with pytest.raises(FatalSessionError, match="BUSY"):
            with Session(addr, give_up=0.2):
                pass
        # ... and served once the session has timed out.
        time.sleep(0.6)
        with Session(addr, give_up=3.0) as fresh:
            obs = fresh.reset(seed=1)
            assert obs["frame"] == 0
            assert fresh.step(0.0)["frame"] == 1


def test_recoverable_errors_keep_the_session(server):
    with Session(server) as s:
        with pytest.raises(SessionError, match="BAD_RESET"):
            s.reset(scenario="diesel")
        s.reset(seed=2, duration=0.3)
        with pytest.raises(SessionError, match="BAD_ACTION"):
            s.step(float("nan"))
        with pytest.raises(SessionError, match="BAD_ACTION"):
            s.step(1.5)
        for _ in range(3):
            obs = s.step(0.0)
        assert obs["truncated"]
        with pytest.raises(SessionError, match="EPISODE_OVER"):
            s.step(0.0)
        s.heartbeat()
        assert s.reset(seed=3)["frame"] == 0


def test_a_late_copy_of_a_refused_step_does_not_refuse_the_next(server):
    # Under load a refused step may be re-sent; its second refusal arrives after the
    # caller has moved on to a good action for the same frame, and must not refuse that.
    with Session(server) as s:
        s.reset(seed=2)
        bad = {"type": "step", "session": s.token, "episode": s.episode, "frame": 0, "action": 1.5}
        with pytest.raises(SessionError, match="BAD_ACTION"):
            s.step(1.5)
        for _ in range(2):  # the re-sent copies, by hand
            s.endpoint.send(bad, s.server)
        time.sleep(0.3)  # their refusals now wait in the socket
        assert s.step(0.0)["frame"] == 1
        # a refusal that does not depend on the action still answers another action at once
        s.reset(seed=2, duration=0.1)
        while not s.step(0.0)["truncated"]:
            pass
        for action in (0.0, -1.0, float("nan")):
            t0 = time.monotonic()
            with pytest.raises(SessionError, match="EPISODE_OVER|BAD_ACTION"):
                s.step(action)
            assert time.monotonic() - t0 < 1.0  # not a time-out


def test_repeated_step_is_answered_from_cache_not_resimulated(server):
    with Session(server) as s:
        s.reset(seed=0)
        first = s.step(1.0)
        # Re-send the same step by hand: the reply must be the cached frame 1.
        msg = {"type": "step", "session": s.token, "episode": s.episode, "frame": 0, "action": -1.0}
        s.endpoint.send(msg, s.server)
        got = None
        while got is None or got.msg is None:
            got = s.endpoint.receive(2.0)
        assert got.msg == first
        assert s.step(0.0)["frame"] == 2


def test_trace_trajectory_from_csv(tmp_path, run_vacc):
    trace = tmp_path / "lead.csv"
    trace.write_text("t_s,speed_mps\n0,20\n5,22\n10,18\n")
    log = tmp_path / "t.csv"
    result = run_vacc("drive", "--controller", "acc", "--scenario", "ev", "--trajectory", str(trace), "--log", str(log))
    assert result.returncode == 0, result.stderr
    assert len(log.read_text().splitlines()) == 1 + 101


@pytest.mark.parametrize(
    "args, message",
    [
        (["--server", "nohost"], "HOST:PORT"),
        (["--trajectory", "missing.csv"], "no such trace file"),
        (["--controller", "warp"], "Invalid value"),
    ],
)
def test_cli_errors_are_clear(tmp_path, args, message, run_vacc):
    base = {"--controller": "acc", "--log": str(tmp_path / "x.csv")}
    for i in range(0, len(args), 2):
        base[args[i]] = args[i + 1]
    result = run_vacc("drive", *[x for kv in base.items() for x in kv])
    assert result.returncode != 0
    assert message in result.stderr
    assert "Traceback" not in result.stderr


def test_serve_refuses_non_loopback_without_flag(run_vacc):
    result = run_vacc("serve", "--host", "0.0.0.0", "--port", "0", "--max-seconds", "0.1")
    assert result.returncode != 0 and "--allow-remote" in result.stderr


def test_serve_sigterm_prints_stats():
    with job([sys.executable, "-m", "sim_server", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        assert proc.stdout.readline().startswith(READY_PREFIX)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "stats" in err


def _images(addr, faults=None, steps=8):
    with Session(addr, image_format="rgb", image_size=(400, 400), faults=faults) as s:
        obs = s.reset(seed=4)
        images = [Session.image(obs)]
        for _ in range(steps):
            images.append(Session.image(s.step(0.2)))
        return images, s.resends


def test_full_rgb_images_survive_fragmentation_and_loss():
    from protocol.faults import FaultConfig

    with local_server() as addr:
        clean, _ = _images(addr)
    with local_server("--faults", "drop=0.1,dup=0.05,reorder=0.05,seed=3") as addr:
        lossy, resends = _images(addr, FaultConfig(drop=0.1, dup=0.05, reorder=0.05, seed=4))
    assert clean[0].shape == (400, 400, 3) and clean[0].nbytes == 480_000
    assert resends > 0
    for a, b in zip(clean, lossy, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(clean[0], clean[-1])


def test_idle_client_keeps_its_session_alive():
    with local_server("--session-timeout", "0.4") as addr:
        with Session(addr) as s:
            s.reset(seed=0)
            time.sleep(1.5)  # busy elsewhere for almost 4 session timeouts
            assert s.step(0.0)["frame"] == 1


def test_spawned_server_exits_when_its_client_is_killed(tmp_path):
    # A client process spawns a server, then dies by SIGKILL (no clean-up runs).
    # As a terminal job: Ctrl-C at its default and unblocked, whatever this worker's state is
    # (a child inherits an ignored or blocked SIGINT across exec); what it inherited goes to stderr.
    script = (
        "import signal, sys, time\n"
        "print('inherited', signal.getsignal(signal.SIGINT), sorted(signal.pthread_sigmask(signal.SIG_BLOCK, [])), file=sys.stderr, flush=True)\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})\n"
        "from agent_client.launcher import local_server\n"
        "with local_server() as addr:\n"
        "    print(addr[1], flush=True)\n"
        "    time.sleep(60)\n"
    )
    client = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    port = int(client.stdout.readline())
    client.kill()
    client.wait()
    client.stdout.close()
    deadline = time.monotonic() + 10
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        while time.monotonic() < deadline:
            try:
                probe.bind(("127.0.0.1", port))  # free again: the orphaned server is gone
                break
            except OSError:
                time.sleep(0.2)
        else:
            pytest.fail(f"orphaned server still holds port {port}")


def test_spawned_server_outlives_a_ctrl_c_to_its_clients_process_group():
    # A terminal's Ctrl-C goes to every process of the foreground job. The client decides
    # when its server goes (after it has saved its work): the server must not get it.
    # As a terminal job: Ctrl-C at its default and unblocked, whatever this worker's state is
    # (a child inherits an ignored or blocked SIGINT across exec); what it inherited goes to stderr.
    script = (
        "import signal, sys, time\n"
        "print('inherited', signal.getsignal(signal.SIGINT), sorted(signal.pthread_sigmask(signal.SIG_BLOCK, [])), file=sys.stderr, flush=True)\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})\n"
        "from agent_client.launcher import local_server\n"
        "from agent_client.session import Session\n"
        "with local_server() as addr, Session(addr, give_up=3) as s:\n"
        "    s.reset(seed=0)\n"
        "    try:  # 'ready' inside it: the signal may land while print returns\n"
        "        print('ready', flush=True)\n"
        "        time.sleep(60)\n"
        "    except KeyboardInterrupt:\n"
        "        time.sleep(1)  # time for a server that got it to die\n"
        "        print('frame', s.step(0.0)['frame'], flush=True)\n"
    )
    with job([sys.executable, "-c", script], own_group=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as client:
        assert client.stdout.readline() == "ready\n"
        os.killpg(client.pid, signal.SIGINT)
        try:
            out, err = client.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(client.pid, signal.SIGKILL)
            out, err = client.communicate()
            pytest.fail(f"the client did not finish within 60 s of its Ctrl-C; stdout {out!r}, stderr {err!r}")
    assert client.returncode == 0 and out == "frame 1\n", err


@pytest.mark.parametrize(
    ("trace_t", "trace_v", "words"),
    [
        ([0.0, 1e300], [10.0, 10.0], "a trace spans at most 14400 s"),
        ([0.0, float(2**63 - 1)], [10.0, 10.0], "a trace spans at most 14400 s"),
        ([0.0, 1.0], [True, False], "trace_t and trace_v must be arrays of numbers"),
        (["0", "1"], [10.0, 10.0], "trace_t and trace_v must be arrays of numbers"),
    ],
)
def test_well_formed_but_bad_traces_get_bad_reset_not_internal(server, trace_t, trace_v, words):
    with Session(server) as s:
        s.episode += 1
        msg = {"type": "reset", "session": s.token, "episode": s.episode, "scenario": "ice", "seed": 0, "trajectory": "trace",
               "trace_t": trace_t, "trace_v": trace_v, "duration": None, "host_speed": None, "gap": None, "set_speed": None, "preroll": None}  # fmt: skip
        with pytest.raises(SessionError, match=f"BAD_RESET.*{words}"):
            s._request(msg, lambda r: r["type"] == "obs", "reset", error_match=lambda e: True)
        assert s.reset(seed=1, duration=1e308)["frame"] == 0  # a huge duration: the whole trajectory, no OverflowError
