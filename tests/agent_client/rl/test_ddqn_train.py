"""Training end to end over real server processes: resume, `vacc train`, `vacc drive --controller ddqn`."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import shlex
import signal
import subprocess
import sys
import time

import pytest
import torch
from click.testing import CliRunner
from proctools import descendants, job, servers_of, state, wait_gone

from agent_client.errors import ResumeError
from agent_client.rl.checkpoint import atomic_save, load_policy
from agent_client.rl.config import Config
from agent_client.rl.train import train
from vacc.cli import main

TINY = Config(
    total_steps=120, learning_starts=30, train_every=4, batch_size=8, buffer_size=400,
    exploration_steps=100, target_sync_every=40, episode_seconds=3.0, checkpoint_every=30,
    eval_every=0, eval_trajectories=(), log_every=20,
)  # fmt: skip


def _state(run_dir):
    ckpt = torch.load(run_dir / "latest.pt", weights_only=True)
    return ckpt


def test_resume_continues_exactly_as_an_uninterrupted_run(tmp_path):
    whole = train(TINY, tmp_path / "whole", progress=False)
    first = train(TINY.__class__(**{**TINY.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    assert first["steps"] == 60
    resumed = train(TINY, tmp_path / "split", resume=True, progress=False)
    assert resumed["steps"] == whole["steps"] == 120
    a, b = _state(tmp_path / "whole"), _state(tmp_path / "split")
    assert a["state"]["global_step"] == b["state"]["global_step"] == 120
    assert a["state"]["episodes"] == b["state"]["episodes"]
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    for key in a["target"]:
        torch.testing.assert_close(a["target"][key], b["target"][key], rtol=0, atol=0)
    assert a["optimizer"]["state"][0]["step"] == b["optimizer"]["state"][0]["step"]
    # the scalars of the split run line up with the whole run's
    names = lambda p: [(r["step"], r["name"]) for r in csv.DictReader(open(p / "scalars.csv")) if not r["name"].startswith("eval/")]  # noqa: E731
    assert names(tmp_path / "whole") == names(tmp_path / "split")


@pytest.mark.parametrize(
    "changes",
    [
        # evaluations at 60, 90 and 120: the one due at 40 waits for the cut episode's end; the split
        # run also evaluates at the first budget's end (45), which learning does not see
        {"eval_trajectories": ("random:3",), "eval_seconds": 0.5, "eval_every": 40},
        # DAgger from a lagged law (its view is state) with the mean decision (its streaks are state)
        {"reward": "eco", "action": "ramp-fine", "teacher": "acc-55", "teacher_lag": 0.5, "teacher_steps": 60, "decision": "mean"},
        {"recurrent": "gru", "frame_stack": 2, "stack_stride": 1, "burn_in": 3, "sequence_length": 6},  # the GRU's state
        {"action": "continuous", "recurrent": "gru", "n_step": 1, "frame_stack": 2, "stack_stride": 1, "burn_in": 3, "sequence_length": 6,
         "conv_channels": (4, 8, 8), "hidden": 32},  # the recurrent actor's state, a continuous decision re-driven
    ],
    ids=["ddqn", "dagger-lagged-mean", "gru", "actor-critic-gru"],
)
def test_a_budget_that_ends_mid_episode_then_grows_continues_exactly_as_a_straight_run(tmp_path, changes):
    """A run whose step budget ended inside an episode, resumed with a larger one, re-drives and
    finishes that episode: it used to draw a new one, so a 150 k run extended to 600 k was not the 600 k run."""
    cfg = Config(**{**TINY.__dict__, **changes})
    train(cfg, tmp_path / "whole", progress=False)
    first = train(Config(**{**cfg.__dict__, "total_steps": 45}), tmp_path / "split", progress=False)  # episodes of 30 steps
    cut = _state(tmp_path / "split")["state"]["cut"]
    assert first["steps"] == 45 and cut["length"] == 15 and len(cut["taken"]) == 15
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = _state(tmp_path / "whole"), _state(tmp_path / "split")
    assert a["state"]["global_step"] == b["state"]["global_step"] == 120
    assert a["state"]["episodes"] == b["state"]["episodes"] and a["state"]["recent_returns"] == b["state"]["recent_returns"]
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    rows = lambda p, kind: [(r["step"], r["name"], r["value"]) for r in csv.DictReader(open(p / "scalars.csv")) if r["name"].startswith(kind)]  # noqa: E731
    assert rows(tmp_path / "whole", "charts/episodic") == rows(tmp_path / "split", "charts/episodic")
    evals = lambda p: [row for row in rows(p, "eval/") if row[0] != "45"]  # noqa: E731
    assert evals(tmp_path / "whole") == evals(tmp_path / "split")
    assert {row[0] for row in evals(tmp_path / "whole")} == ({"60", "90", "120"} if cfg.eval_trajectories else set())


def test_a_cut_episode_that_re_drives_elsewhere_is_refused_in_one_line(tmp_path):
    train(Config(**{**TINY.__dict__, "total_steps": 45}), tmp_path / "run", progress=False)
    ckpt = torch.load(tmp_path / "run" / "latest.pt", weights_only=True)
    ckpt["state"]["cut"]["taken"][3][0] = (ckpt["state"]["cut"]["taken"][3][0] + 7) % 21  # another action than was taken
    atomic_save(ckpt, tmp_path / "run" / "latest.pt")  # with its digest: a file that reads, telling another episode
    with pytest.raises(ResumeError, match=r"the episode cut at step 45 re-drove to another camera frame"):
        train(TINY, tmp_path / "run", resume=True, progress=False)


def test_a_preroll_run_trains_evaluates_and_resumes_exactly(tmp_path):
    # Episodes start after the camera's pre-roll; the replay keeps those frames for the first stacks.
    cfg = Config(**{**TINY.__dict__, "preroll": True, "train_trajectories": ("stopped", "random"), "eval_trajectories": ("stopped:1",), "eval_seconds": 1.0})
    whole = train(cfg, tmp_path / "whole", progress=False)
    train(Config(**{**cfg.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = _state(tmp_path / "whole"), _state(tmp_path / "split")
    assert whole["steps"] == 120 and a["state"]["episodes"] == b["state"]["episodes"] > 1
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    assert whole["last_eval"] and json.loads((tmp_path / "whole" / "config.json").read_text())["preroll"] is True


def test_resume_may_change_when_it_evaluates_saves_and_logs(tmp_path):
    """eval_every, checkpoint_every and log_every touch neither learning nor the RNG;
    the held-out "random:S" evaluation is the episode `vacc drive --seed S` drives."""
    held_out = Config(**{**TINY.__dict__, "eval_trajectories": ("random:3",), "eval_seconds": 1.0})
    train(held_out, tmp_path / "whole", progress=False)  # one evaluation, at the end
    train(Config(**{**held_out.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    changed = Config(**{**held_out.__dict__, "eval_every": 40, "checkpoint_every": 45, "log_every": 10, "keep_evals": True})
    train(changed, tmp_path / "split", resume=True, progress=False)
    a, b = _state(tmp_path / "whole"), _state(tmp_path / "split")
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    evals = lambda p: {int(r["step"]): float(r["value"]) for r in csv.DictReader(open(p / "scalars.csv")) if r["name"] == "eval/gap_rmse_m/random:3"}  # noqa: E731
    whole, split = evals(tmp_path / "whole"), evals(tmp_path / "split")
    assert list(whole) == [120] and list(split) == [60, 90, 120]  # at episode ends (30 steps each)
    assert split[120] == whole[120]
    # Each evaluation after the resume kept its policy; the last is the whole run's best.pt.
    assert sorted(p.name for p in (tmp_path / "split" / "evals").iterdir()) == ["120.pt", "90.pt"]
    kept, best = load_policy(tmp_path / "split" / "evals" / "120.pt"), load_policy(tmp_path / "whole" / "best.pt")
    for key, value in best[0].state_dict().items():
        torch.testing.assert_close(kept[0].state_dict()[key], value, rtol=0, atol=0)
    assert not (tmp_path / "whole" / "evals").exists()

    log = tmp_path / "drive.csv"
    args = ["drive", "--controller", "ddqn", "--checkpoint", str(tmp_path / "whole" / "best.pt"), "--trajectory", "random", "--seed", "3", "--duration", "1", "--log", str(log), "--quiet"]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    gaps = [float(r["gap"]) for r in csv.DictReader(open(log))]
    assert float(f"{(sum((g - 55.0) ** 2 for g in gaps) / len(gaps)) ** 0.5:.6g}") == whole[120]


def test_bad_evaluation_trajectories_fail_before_training(tmp_path):
    for name in ("test-5", "random", "random:x", "random:-1"):
        with pytest.raises(ValueError, match=f"{name!r}.*random:SEED"):
            Config(eval_trajectories=(name,))
    result = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--out", str(tmp_path / "r"), "--eval-trajectories", "test-1,tset-2"])
    assert result.exit_code == 2
    assert "--eval-trajectories" in result.output and "'tset-2'" in result.output
    assert not (tmp_path / "r").exists()


def test_resume_refuses_other_settings_and_missing_files(tmp_path):
    from agent_client.errors import InputFileError

    with pytest.raises(InputFileError, match="latest.pt.*not found"):
        train(TINY, tmp_path / "none", resume=True, progress=False)
    train(Config(**{**TINY.__dict__, "total_steps": 30}), tmp_path / "run", progress=False)
    with pytest.raises(InputFileError, match="other settings.*gamma"):
        train(Config(**{**TINY.__dict__, "gamma": 0.9}), tmp_path / "run", resume=True, progress=False)
    [replay] = (tmp_path / "run").glob("replay-*.npz")
    replay.unlink()
    with pytest.raises(InputFileError, match="replay-30.npz"):
        train(TINY, tmp_path / "run", resume=True, progress=False)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "run"
    args = [
        "train", "--reward", "force", "--scenario", "ice", "--steps", "200", "--out", str(out),
        "--learning-starts", "50", "--episode-seconds", "5", "--buffer-size", "1000",
        "--exploration-steps", "100", "--eval-every", "100", "--eval-seconds", "1",
        "--eval-trajectories", "test-1", "--quiet", "--seed", "3", "--log-every", "20", "--crash-reward", "-1",
    ]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    return out, result.output


def test_train_cli_writes_the_run_folder(trained_run):
    out, output = trained_run
    assert "trained 200 steps" in output and "test-1: gap RMSE" in output
    for name in ("config.json", "scalars.csv", "latest.pt", "best.pt", "summary.json"):
        assert (out / name).is_file(), name
    assert [p.name for p in out.glob("replay-*.npz")] == ["replay-200.npz"]
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["reward"] == "force" and cfg["total_steps"] == 200 and cfg["seed"] == 3 and cfg["crash_reward"] == -1.0
    names = {r["name"] for r in csv.DictReader(open(out / "scalars.csv"))}
    for name in ("charts/episodic_return", "charts/SPS", "charts/epsilon", "losses/td_loss", "losses/q_values", "eval/gap_rmse_m", "eval/collisions"):
        assert name in names, name
    assert (out / "best.pt").stat().st_size < 5e6
    q, loaded = load_policy(out / "best.pt")
    assert loaded.reward == "force"
    assert not list(out.glob("*.tmp"))


def test_a_training_checkpoint_exports_as_a_policy_with_its_weights(trained_run, tmp_path):
    out, _ = trained_run
    dst = tmp_path / "policy.pt"
    cli = [sys.executable, "-m", "vacc", "checkpoint", "export", str(out / "latest.pt"), str(dst)]
    done = subprocess.run(cli, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "at step 200" in done.stdout, done.stderr
    assert dst.stat().st_size < 5e6 < (out / "latest.pt").stat().st_size  # no target, optimizer or RNG
    policy, training = torch.load(dst, weights_only=True), torch.load(out / "latest.pt", weights_only=True)
    assert policy["kind"] == "policy" and policy["extra"]["step"] == 200 and policy["config"] == training["config"]
    for key, value in training["model"].items():
        torch.testing.assert_close(policy["model"][key], value, rtol=0, atol=0)
    before = dst.read_bytes()
    done = subprocess.run(cli, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "exists" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert dst.read_bytes() == before


def test_drive_ddqn_writes_a_valid_log(trained_run, tmp_path):
    out, _ = trained_run
    log = tmp_path / "ddqn.csv"
    result = CliRunner().invoke(
        main, ["drive", "--controller", "ddqn", "--checkpoint", str(out / "best.pt"), "--trajectory", "test-2", "--duration", "3", "--log", str(log)]
    )
    assert result.exit_code == 0, result.output
    assert "ddqn on ice/test-2" in result.output
    rows = list(csv.DictReader(open(log)))
    assert len(rows) == 31
    for col in ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision"):
        assert col in rows[0]
    forces = {round(float(r["force"]), 1) for r in rows[1:]}
    assert forces <= {round(-1 + 0.1 * a, 1) for a in range(21)}


def test_drive_ddqn_bad_checkpoint_is_a_clear_error(tmp_path):
    bad = tmp_path / "broken.pt"
    bad.write_bytes(b"\x00" * 100)
    runner = CliRunner()
    result = runner.invoke(main, ["drive", "--controller", "ddqn", "--checkpoint", str(bad), "--log", str(tmp_path / "x.csv")])
    assert result.exit_code == 2
    assert "broken.pt" in result.output and "Traceback" not in result.output
    result = runner.invoke(main, ["drive", "--controller", "ddqn", "--log", str(tmp_path / "x.csv")])
    assert result.exit_code == 2 and "--checkpoint" in result.output


def test_init_from_must_match_the_stack(trained_run, tmp_path):
    from agent_client.errors import InputFileError

    out, _ = trained_run
    with pytest.raises(InputFileError, match="best.pt.*stride"):
        train(Config(**{**TINY.__dict__, "stack_stride": 3, "init_from": str(out / "best.pt")}), tmp_path / "ft", progress=False)


def test_zoom2_trains_and_drives_with_full_resolution_frames(tmp_path):
    """A zoom-2 checkpoint makes `vacc drive` ask for the 400x400 camera it was trained on."""
    out = tmp_path / "z2"
    summary = train(Config(**{**TINY.__dict__, "total_steps": 40, "learning_starts": 20, "zoom": 2}), out, progress=False)
    assert summary["steps"] == 40
    q, cfg = load_policy(out / "latest.pt")
    assert cfg.zoom == 2
    log = tmp_path / "z2.csv"
    result = CliRunner().invoke(
        main, ["drive", "--controller", "ddqn", "--checkpoint", str(out / "latest.pt"), "--trajectory", "test-1", "--duration", "2", "--log", str(log)]
    )
    assert result.exit_code == 0, result.output
    assert len(list(csv.DictReader(open(log)))) == 21
    with pytest.raises(Exception, match="zoom"):
        train(Config(**{**TINY.__dict__, "init_from": str(out / "latest.pt")}), tmp_path / "ft", progress=False)


def test_checkpoints_without_a_zoom_are_the_papers_pipeline(tmp_path):
    """Models saved before the zoom setting existed (e.g. models/ice-gap.pt) load as zoom 1."""
    from agent_client.rl.checkpoint import save_policy
    from agent_client.rl.network import QNetwork

    path = tmp_path / "old.pt"
    save_policy(QNetwork(), Config(), path)
    ckpt = torch.load(path, weights_only=True)
    del ckpt["config"]["zoom"], ckpt["sha256"]
    ckpt["version"] = 1  # as written before checkpoints carried a digest
    torch.save(ckpt, path)
    assert load_policy(path)[1].zoom == 1


def test_sigterm_stops_with_a_checkpoint_and_a_second_aborts(tmp_path):
    """`kill PID` (SIGTERM to the trainer alone): a checkpoint, exit 143 and the resume
    command; a second kill during the stop would abort, which the first must not need."""
    out = tmp_path / "run"
    args = [sys.executable, "-m", "vacc", "train", "--reward", "gap", "--steps", "100000", "--learning-starts", "20",
            "--buffer-size", "2000", "--episode-seconds", "3", "--eval-every", "0", "--checkpoint-every", "100000",
            "--quiet", "--out", str(out)]  # fmt: skip
    with job(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        deadline = time.monotonic() + 120
        while not (out / "scalars.csv").exists():
            assert proc.poll() is None and time.monotonic() < deadline, "training did not start"
            time.sleep(0.2)
        time.sleep(2)
        tree = descendants(proc.pid)
        proc.terminate()
        stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 143, stderr
    assert "SIGTERM: stopping at the next point it can resume from, with a checkpoint" in stderr and "Traceback" not in stderr, stderr
    assert "stopped by SIGTERM at step" in stdout and "--resume" in stdout, stdout
    assert (out / "latest.pt").exists() and wait_gone(tree) == []


def test_first_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(tmp_path):
    """A terminal's Ctrl-C goes to the whole foreground process group: the spawned server
    must outlive it, so that the step in flight ends and the checkpoint is written."""
    out = tmp_path / "run"
    args = [sys.executable, "-m", "vacc", "train", "--reward", "gap", "--steps", "100000", "--learning-starts", "20",
            "--buffer-size", "2000", "--episode-seconds", "3", "--eval-trajectories", "test-1", "--eval-seconds", "0.5",
            "--eval-every", "0", "--checkpoint-every", "100000", "--quiet", "--out", str(out)]  # fmt: skip
    # its own session: a process group of its own, as a job started from a terminal
    with job(args, own_group=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        deadline = time.monotonic() + 120
        while not (out / "scalars.csv").exists() or not servers_of([proc.pid]):  # the learner and its server are up
            assert proc.poll() is None and time.monotonic() < deadline, "training did not start"
            time.sleep(0.2)
        time.sleep(5)  # some steps
        tree = descendants(proc.pid)
        (server,) = servers_of([proc.pid])
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C, as a terminal sends it: to every process of the job
        while state(server) not in ("(Z)", "(gone)") and time.monotonic() < deadline + 60:
            time.sleep(0.005)
        # the trainer reaps its server after the checkpoint; one that died of the Ctrl-C went first
        saved_before_the_server_went = (out / "latest.pt").exists()
        stdout, stderr = proc.communicate(timeout=120)
    assert saved_before_the_server_went, "the Ctrl-C reached the spawned server"
    assert proc.returncode == 130, stderr
    assert "Ctrl-C again to abort" in stderr and "Traceback" not in stderr, stderr
    assert (out / "latest.pt").exists() and not list(out.glob("*.tmp"))
    assert wait_gone(tree) == [], "processes left behind"
    step = torch.load(out / "latest.pt", weights_only=True)["state"]["global_step"]
    assert 0 < step < 100000
    # the printed command resumes it, its settings read back from config.json
    (command,) = [line.split("continue with: ", 1)[1] for line in stdout.splitlines() if "continue with: " in line]
    assert shlex.split(command)[:2] == ["vacc", "train"] and "--resume" in command
    resumed = subprocess.run([sys.executable, "-m", "vacc", *shlex.split(command)[1:], "--steps", str(step + 30), "--quiet"],
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr
    assert torch.load(out / "latest.pt", weights_only=True)["state"]["global_step"] == step + 30


TRAIN_TINY = [sys.executable, "-m", "vacc", "train", "--reward", "gap", "--steps", "40", "--learning-starts", "20",
              "--buffer-size", "500", "--episode-seconds", "3", "--eval-every", "0", "--eval-trajectories", "test-1",
              "--eval-seconds", "0.5", "--quiet"]  # fmt: skip
OLD_RUN = ("config.json", "summary.json", "scalars.csv", "latest.pt", "best.pt", "replay-50.npz", "latest.pt.tmp",
           "events.out.tfevents.1700000000.old-host.1.0")  # fmt: skip
NOT_THE_RUNS = ("notes.md", "best.pt.bak", "eval/events.out.tfevents.1700000000.old-host.2.0", "eval/latest.pt")


def _folder_with_an_old_run(out):
    """An old run's files (garbage bytes), and the researcher's own files beside them and below."""
    (out / "eval").mkdir(parents=True)
    for name in (*OLD_RUN, *NOT_THE_RUNS):
        (out / name).write_bytes(b"old " + name.encode())
    (out / "config.json").write_text("{}")


def _snapshot(folder):
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else b"", p.stat().st_mtime_ns) for p in folder.rglob("*")}


def test_an_out_that_holds_a_run_is_refused_without_resume_or_overwrite(tmp_path):
    out = tmp_path / "run"
    _folder_with_an_old_run(out)
    before = _snapshot(out)
    for extra in ([], ["--resume", "--overwrite"]):
        r = subprocess.run([*TRAIN_TINY, "--out", str(out), *extra], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, r.stderr
        assert "--resume" in r.stderr and "--overwrite" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert _snapshot(out) == before


def test_overwrite_removes_the_old_runs_files_tensorboard_events_included_and_nothing_else(tmp_path):
    from agent_client.rl.cli import run_files

    out = tmp_path / "run"
    _folder_with_an_old_run(out)
    theirs = {name: (out / name).read_bytes() for name in NOT_THE_RUNS}
    r = subprocess.run([*TRAIN_TINY, "--out", str(out), "--overwrite"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"--overwrite removed {len(OLD_RUN)} files of the previous run" in r.stderr
    assert {name: (out / name).read_bytes() for name in NOT_THE_RUNS} == theirs
    assert not (out / "replay-50.npz").exists() and not list(out.glob("*.tmp"))
    events = [p.name for p in out.glob("events.out.tfevents.*")]
    assert OLD_RUN[-1] not in events and len(events) == (1 if importlib.util.find_spec("tensorboard") else 0), events
    assert torch.load(out / "latest.pt", weights_only=True)["state"]["global_step"] == 40
    load_policy(out / "best.pt")
    # what this run wrote is what the next --overwrite removes: RUN_FILES names every file
    assert {p.name for p in run_files(out)} == {p.name for p in out.iterdir() if p.is_file()} - set(NOT_THE_RUNS)


def test_train_traffic_goes_to_the_training_server_only(tmp_path):
    # The training stream sees the busier road; best.pt is chosen on the default one, as
    # vacc drive and vacc evaluate drive it.
    args = ["--steps", "40", "--learning-starts", "20", "--batch-size", "8", "--buffer-size", "200", "--episode-seconds", "2",
            "--eval-trajectories", "stopped:1", "--eval-seconds", "1", "--eval-every", "0", "--train-traffic", "7", "--train-sun-elevation", "0.35,0.6"]  # fmt: skip
    cmd = [sys.executable, "-m", "vacc", "-vv", "train", "--reward", "gap", *args, "--out", str(tmp_path / "run")]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    started = [line for line in result.stderr.splitlines() if "starting a simulator server: " in line]
    assert len(started) == 2 and sum("--traffic 7 --sun-elevation 0.35,0.6" in line for line in started) == 1, started
    assert sum("--sun-elevation" in line for line in started) == 1, started  # the evaluation server: the default sun
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["train_traffic"] == 7 and config["train_sun_elevation"] == [0.35, 0.6]
    bad = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--train-traffic", "11", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "--train-traffic" in bad.output and "[0, 10]" in bad.output, bad.output
    bad = CliRunner().invoke(main, ["train", "--reward", "gap", "--steps", "10", "--train-sun-elevation", "0.6,0.4", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "--train-sun-elevation" in bad.output and "LOW <= HIGH" in bad.output, bad.output
    assert not (tmp_path / "bad").exists()


def test_a_ctrl_c_mid_episode_resumes_exactly_as_an_uninterrupted_run(tmp_path):
    """The stop waits for the episode's end: a checkpoint cut mid-episode started a new episode
    on resume, and a rebuilt ice-gap drifted from its shipped weights after one Ctrl-C."""
    base = [sys.executable, "-m", "vacc", "train", "--quiet"]
    steps = ["--reward", "gap", "--steps", "600", "--learning-starts", "20", "--buffer-size", "1000", "--episode-seconds", "3",
             "--eval-every", "150", "--eval-trajectories", "random:3", "--eval-seconds", "0.5", "--checkpoint-every", "100000"]  # fmt: skip
    whole, split = tmp_path / "whole", tmp_path / "split"
    done = subprocess.run([*base, *steps, "--out", str(whole)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    with job([*base, *steps, "--out", str(split)], own_group=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        deadline = time.monotonic() + 300
        scalars = split / "scalars.csv"
        # two episodes in (30 steps each): the Ctrl-C lands somewhere inside the third or later
        while not (scalars.exists() and scalars.read_text().count("charts/episodic_return") >= 2):
            assert proc.poll() is None and time.monotonic() < deadline, "training did not get going"
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 130, stderr
    stopped = torch.load(split / "latest.pt", weights_only=True)["state"]["global_step"]
    ends = {int(r["step"]) for r in csv.DictReader(open(split / "scalars.csv")) if r["name"] == "charts/episodic_return"}
    assert 0 < stopped < 600 and stopped in ends, stopped  # at an episode's end
    resumed = subprocess.run([*base, "--resume", "--out", str(split)], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    a, b = _state(whole), _state(split)
    assert a["state"]["global_step"] == b["state"]["global_step"] == 600
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    evals = lambda p: [(r["step"], r["name"], r["value"]) for r in csv.DictReader(open(p / "scalars.csv")) if r["name"].startswith("eval/")]  # noqa: E731
    assert evals(whole) == evals(split)  # every evaluation, the same, also one due where it stopped
