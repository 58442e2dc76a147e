"""A platoon server over 127.0.0.1: one client per seat, in lockstep (sim_server.seats)."""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

import pytest
from proctools import job

from agent_client.errors import FatalSessionError
from agent_client.session import Session
from protocol.messages import ErrorCode
from sim_server.platoon import PlatoonWorld

FIELDS = ("frame", "t", "v_host", "v_lead", "gap", "accel", "force", "terminated", "truncated", "reason")


def _drive(addr, seat, out, *, scenario, preroll, action, duration=3.0, key=None, stall_at=None):
    """A seat's client in a thread: reset, then a constant ``action`` to the end; obs kept in ``out[seat]``."""
    try:
        with Session(addr, seat=seat, key=key, give_up=5.0) as s:
            obs = s.reset(scenario, seed=7, trajectory="test-2", duration=duration, preroll=preroll)
            rows = [obs]
            while not (obs["terminated"] or obs["truncated"]):
                if stall_at is not None and obs["frame"] == stall_at:
                    time.sleep(4.0)  # a stalled client: the platoon gives up on it meanwhile
                    return
                obs = s.step(action if obs["frame"] >= 0 else 0.0)
                rows.append(obs)
            out[seat] = rows
    except Exception as exc:  # noqa: BLE001 - the test reads what each seat saw
        out[seat] = exc


def _run_seats(addr, specs, **kw):
    out: dict[int, object] = {}
    threads = [threading.Thread(target=_drive, args=(addr, i, out), kwargs={**spec, **kw}) for i, spec in enumerate(specs)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return out


SPECS = [
    {"scenario": "ev", "preroll": 0, "action": 0.2},
    {"scenario": "ice", "preroll": 4, "action": -0.1},  # a policy's camera pre-roll: its reset answered at frame -4
    {"scenario": "ev", "preroll": 0, "action": 0.3},
]


def test_seats_drive_exactly_as_the_in_process_platoon(spawn):
    with spawn("--port", "0", "--followers", "3") as (_, addr):
        out = _run_seats(addr, SPECS)
    assert all(isinstance(out[i], list) for i in range(3)), out
    assert [out[i][0]["frame"] for i in range(3)] == [0, -4, 0]  # each seat's reset is answered at its own first frame
    world = PlatoonWorld(3)
    states = world.reset([s["scenario"] for s in SPECS], 7, "test-2", duration=3.0, preroll=4)
    expected = [[st] for st in states]
    while not world.over:
        states = world.step([s["action"] if states[0].frame >= 0 else 0.0 for s in SPECS])
        for i, st in enumerate(states):
            expected[i].append(st)
    for i, spec in enumerate(SPECS):
        got = [tuple(o[k] for k in FIELDS) for o in out[i]]
        want = [tuple(getattr(st, k) for k in FIELDS) for st in expected[i] if st.frame >= -spec["preroll"]]
        assert got == want, f"seat {i}"  # float for float: the same platoon
    assert out[0][-1]["frame"] == 30 and out[0][-1]["reason"] == "end"


def test_a_stalled_seat_ends_every_session_naming_it(spawn):
    with spawn("--port", "0", "--followers", "3", "--seat-timeout", "1") as (_, addr):
        started = time.monotonic()
        out = _run_seats(addr, [{**s, "stall_at": 5 if i == 1 else None} for i, s in enumerate(SPECS)])
        waited = time.monotonic() - started
    for i in (0, 2):
        exc = out[i]
        assert isinstance(exc, FatalSessionError) and exc.code == ErrorCode.SEAT_LOST, exc
        assert "seat 1 (client 127.0.0.1:" in str(exc) and "no action for frame 5 within 1 s" in str(exc)
    assert waited < 8  # the give-up (1 s) and the stalled thread's sleep, not a client's timeout


def test_seat_requests_that_cannot_be_met_are_refused_in_one_line(spawn):
    with spawn("--port", "0", "--followers", "2") as (_, addr):
        refused = time.monotonic()
        with pytest.raises(FatalSessionError, match="BAD_MESSAGE: seat 5 outside 0..1"):
            Session(addr, seat=5, give_up=3.0).open()
        assert time.monotonic() - refused < 1.0  # refused at once, not retried as a busy seat
        with Session(addr, seat=1, give_up=1.0) as held:
            assert held.welcome["seat"] == 1 and held.welcome["seats"] == 2
            with pytest.raises(FatalSessionError, match="BUSY: seat 1 is taken"):
                Session(addr, seat=1, give_up=0.5).open()
            with Session(addr, give_up=1.0) as any_seat:  # no seat asked: the first free one
                assert any_seat.seat == 0
    with spawn("--port", "0") as (_, addr):
        with pytest.raises(FatalSessionError, match="this server drives one car: there is no seat 2"):
            Session(addr, seat=2, give_up=1.0).open()


def test_keyed_seats_each_hold_their_own_keys(spawn, tmp_path):
    from protocol.auth import load_key

    key_file = tmp_path / "k"
    key_file.write_bytes(b"k" * 32)
    key = load_key(str(key_file))
    with spawn("--port", "0", "--followers", "2", "--key-file", str(key_file)) as (_, addr):
        out = _run_seats(addr, SPECS[:2], key=key, duration=1.0)
        with pytest.raises(Exception, match="no reply|never reached"):
            Session(addr, give_up=0.5).open()  # without the key, not even a seat's welcome
    assert all(isinstance(out[i], list) and out[i][-1]["reason"] == "end" for i in range(2)), out


def test_vacc_platoon_of_ten_clients_is_byte_identical_under_loss(tmp_path, run_vacc):
    followers = ",".join(["acc", "hdm", "acc@ev", "acc", "hdm@ev", "acc", "acc", "hdm", "acc@ev", "acc"])
    base = ["platoon", "--followers", followers, "--lead", "test-3", "--duration", "3", "--no-figures"]
    clean = run_vacc(*base, "--out", str(tmp_path / "clean"))
    assert clean.returncode == 0, clean.stderr
    assert "lead to last: speed RMS" in clean.stdout
    faults = "drop=0.2,dup=0.1,reorder=0.1"
    lossy = run_vacc(*base, "--out", str(tmp_path / "lossy"), "--faults", faults + ",seed=5", "--server-faults", faults + ",seed=6")
    assert lossy.returncode == 0, lossy.stderr
    for i in range(1, 11):
        a, b = (tmp_path / d / f"car-{i}.csv" for d in ("clean", "lossy"))
        assert a.read_bytes() == b.read_bytes(), f"car {i}"
        card = json.loads((tmp_path / "lossy" / f"car-{i}.card.json").read_text())
        assert card["road"]["seat"] == i - 1 and card["road"]["seats"] == 10
    figures = json.loads((tmp_path / "clean" / "platoon.json").read_text())["figures"]
    metrics = run_vacc("metrics", str(tmp_path / "clean"), "--json")
    assert metrics.returncode == 0, metrics.stderr
    assert json.loads(metrics.stdout)["amp_lead_last_speed_rms"] == figures["amp_lead_last_speed_rms"]


def test_a_killed_client_ends_the_others_naming_its_seat(tmp_path, spawn):
    with spawn("--port", "0", "--followers", "3", "--seat-timeout", "1.5") as (_, addr):
        where = f"{addr[0]}:{addr[1]}"
        drive = [sys.executable, "-m", "vacc", "drive", "--server", where, "--controller", "acc", "--trajectory", "test-1", "--quiet"]
        with (
            job([*drive, "--seat", "0", "--log", str(tmp_path / "c0.csv")], stderr_path=tmp_path / "e0") as c0,
            job([*drive, "--seat", "1", "--log", str(tmp_path / "c1.csv")], stderr_path=tmp_path / "e1") as c1,
            job([*drive, "--seat", "2", "--log", str(tmp_path / "c2.csv")], stderr_path=tmp_path / "e2") as c2,
        ):
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and len((tmp_path / "c1.csv").read_text().splitlines() if (tmp_path / "c1.csv").exists() else []) < 20:
                time.sleep(0.05)
            c1.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            codes = [c0.wait(10), c2.wait(10)]
            took = time.monotonic() - killed
    assert codes == [1, 1]
    assert took < 1.5 + 3.0  # the give-up, and the clients' exit
    for i in (0, 2):
        err = (tmp_path / f"e{i}").read_text()
        assert "SEAT_LOST: platoon gave up: seat 1 (client 127.0.0.1:" in err and f"log so far: {tmp_path / f'c{i}.csv'}" in err
        assert len((tmp_path / f"c{i}.csv").read_text().splitlines()) > 20  # every row so far kept


def test_drive_seat_needs_a_server(run_vacc, tmp_path):
    r = run_vacc("drive", "--controller", "acc", "--seat", "1", "--log", str(tmp_path / "x.csv"))
    assert r.returncode == 2 and "--seat needs --server" in r.stderr


def test_a_reset_mid_episode_abandons_it_for_every_seat(spawn):
    from agent_client.errors import SessionError

    with spawn("--port", "0", "--followers", "2") as (_, addr), Session(addr, seat=0) as s0, Session(addr, seat=1) as s1:
        both = threading.Thread(target=s1.reset, kwargs={"trajectory": "test-1", "duration": 5.0})
        both.start()
        s0.reset(trajectory="test-1", duration=5.0)
        both.join()
        stepped = threading.Thread(target=s1.step, args=(0.0,))
        stepped.start()
        s0.step(0.0)
        stepped.join()
        again = threading.Thread(target=lambda: s0.reset(trajectory="test-2", duration=5.0))
        again.start()  # seat 0 starts over while seat 1 is mid-episode
        time.sleep(0.3)
        with pytest.raises(SessionError, match="EPISODE_OVER: seat 0 asked for a new episode at frame 1"):
            s1.step(0.0)
        first = s1.reset(trajectory="test-2", duration=5.0)
        again.join()
        assert first["frame"] == 0 and s1.episode == 1 and s0.episode == 1
