"""`vacc reproduce --smoke`: every recipe still runs end to end, and a run killed mid-stage
resumes to the same model as one that never stopped."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import torch
from proctools import reap_job

from agent_client.rl.checkpoint import read_checkpoint
from vacc.recipes import RECIPES_DIR
from vacc.reproduce import SEED_STRIDE, duration, file_sha256, shifted_seed

ROOT = Path(__file__).resolve().parents[2]
RECIPES = sorted(p.stem for p in RECIPES_DIR.glob("*.toml"))


def _reproduce(name: str, out: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "vacc", "reproduce", name, "--out", str(out), "--smoke", "--quiet", *extra],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _finish(proc: subprocess.Popen, timeout: float = 600) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        reap_job(proc, group=True)
    return out


EV_FORCE_CHAIN = Path(__file__).parent / "data" / "ev-force-chain.toml"  # ev-force's chain until 2026-12-06: four train stages
SHARED = str(EV_FORCE_CHAIN)  # its smoke run is also the kill test's uninterrupted run: the kill test checks it


def test_seed_shift_rule():
    from vacc.recipes import load_recipe

    r = load_recipe(EV_FORCE_CHAIN)
    assert shifted_seed(72, r, r.seed) == 72 and shifted_seed(72, r, r.seed + 2) == 72 + 2 * SEED_STRIDE


def test_a_tail_replicate_keeps_the_recipe_seeds_before_its_first_stage(tmp_path):
    import click

    from vacc.recipes import load_recipe
    from vacc.reproduce import replicate_of, reproduce, stage_key

    r = load_recipe(EV_FORCE_CHAIN)
    plain = {"seed": r.seed, "smoke": False, "reseed_from": None}
    tail = {"seed": r.seed + 1, "smoke": False, "reseed_from": "ev-force"}
    assert [replicate_of(r, s, tail) for s in r.stages] == [r.seed, r.seed, r.seed + 1, r.seed + 1]
    first, last = r.stage("gap-scratch"), r.stage("mix")
    assert stage_key(r, first, plain, []) == stage_key(r, first, tail, [])  # the same stage: reusable
    assert stage_key(r, last, plain, ["a" * 64]) != stage_key(r, last, tail, ["a" * 64])  # another seed
    assert stage_key(r, last, plain, ["a" * 64]) != stage_key(r, last, plain, ["b" * 64])  # other parents
    assert stage_key(r, first, plain, []) != stage_key(r, first, {**plain, "smoke": True}, [])
    with pytest.raises(click.ClickException, match="--reseed-from nope: ev-force has no such stage .it has gap-scratch, ev-gap, ev-force, mix."):
        reproduce(r, tmp_path / "x", seed=1, reseed_from="nope")
    with pytest.raises(click.ClickException, match="--reuse .*missing: no such folder"):
        reproduce(r, tmp_path / "x", reuse=tmp_path / "missing")
    assert not (tmp_path / "x").exists()


def test_the_recipes_reseed_from_sets_the_tail_and_no_seed_goes_below_zero(tmp_path):
    """A recipe written for replicate 3 of its tail (as ice-gap's): --seed 0 replicates only the
    tail, by default; a replicate that would take an earlier stage's seed below 0 is refused."""
    import click

    from vacc.recipes import load_recipe, parse_recipe
    from vacc.reproduce import replicate_of, reproduce

    content = tomllib.loads(load_recipe(EV_FORCE_CHAIN).path.read_text())
    content["recipe"].update(seed=3, reseed_from="ev-force")
    content["stage"][2]["seed"] += 3 * SEED_STRIDE
    r = parse_recipe(content, tmp_path / "ev-force.toml")
    default = {"seed": 0, "smoke": False, "reseed_from": None}
    assert [replicate_of(r, s, default) for s in r.stages] == [3, 3, 0, 0]
    assert [replicate_of(r, s, {**default, "reseed_from": "mix"}) for s in r.stages] == [3, 3, 3, 0]
    assert shifted_seed(r.stages[2].options["seed"], r, 0) == load_recipe(EV_FORCE_CHAIN).stage("ev-force").options["seed"]
    with pytest.raises(click.ClickException, match=r"--seed 0: stage gap-scratch's seed would be .* below 0 .*give --seed >= 3"):
        reproduce(r, tmp_path / "x", seed=0, reseed_from="gap-scratch")
    assert not (tmp_path / "x").exists()


def test_a_record_of_another_key_is_reused_only_where_it_made_the_known_weights(tmp_path, capsys):
    """ice-gap's rebuilt first stage predates stage keys; ice-eco's first stage is the same
    stage, and its known weights say so: reusable at the recipe's seed, never otherwise. So is
    a keyed record of a stage whose inert options differ, where it made the known weights."""
    from vacc.recipes import load_recipe
    from vacc.reproduce import _reuse, file_sha256

    stage = load_recipe("ice-eco").stage("scratch")
    src = tmp_path / "src" / "scratch"
    src.mkdir(parents=True)
    (src / "scratch.pt").write_bytes(b"weights")
    record = {"sha256": file_sha256(src / "scratch.pt"), "weights_sha256": stage.known_weights}
    (src / "done.json").write_text(json.dumps(record))
    assert _reuse(stage, "k" * 64, tmp_path / "a", tmp_path / "src", known=False) is None  # a replicate or --smoke
    got = _reuse(stage, "k" * 64, tmp_path / "b", tmp_path / "src", known=True)
    assert got is not None and got["stage_key"] == "k" * 64 and (tmp_path / "b" / "scratch" / "scratch.pt").read_bytes() == b"weights"
    assert json.loads((tmp_path / "b" / "scratch" / "done.json").read_text())["stage_key"] == "k" * 64
    assert "it made this stage's known weights" in capsys.readouterr().err
    (src / "done.json").write_text(json.dumps({**record, "weights_sha256": "0" * 64}))  # other weights
    assert _reuse(stage, "k" * 64, tmp_path / "c", tmp_path / "src", known=True) is None
    (src / "done.json").write_text(json.dumps({**record, "weights_sha256": "0" * 64, "stage_key": "j" * 64}))  # another stage
    assert _reuse(stage, "k" * 64, tmp_path / "d", tmp_path / "src", known=True) is None
    assert not any((tmp_path / d).exists() for d in "acd")
    (src / "done.json").write_text(json.dumps({**record, "stage_key": "j" * 64}))  # another key, the known weights
    got = _reuse(stage, "k" * 64, tmp_path / "e", tmp_path / "src", known=True)
    assert got is not None and got["stage_key"] == "k" * 64 and got["reused_from"] == str(src)


def test_a_stage_another_recipe_names_otherwise_is_reused_by_its_key(tmp_path, capsys):
    """A stage whose keyed record sits under another stage name (here ev-eco's ``dagger``, its
    record written as ``ev-gap`` with the same key): the record is found, copied under this
    stage's name, and says where from."""
    from vacc.recipes import load_recipe
    from vacc.reproduce import _reuse, file_sha256

    stage = load_recipe("ev-eco").stage("dagger")
    src = tmp_path / "src" / "ev-gap"
    src.mkdir(parents=True)
    (src / "ev-gap.pt").write_bytes(b"weights")
    (tmp_path / "src" / "gates").mkdir()  # a folder without a record is passed over
    (src / "done.json").write_text(json.dumps({"output": "ev-gap.pt", "sha256": file_sha256(src / "ev-gap.pt"), "stage_key": "k" * 64}))
    assert _reuse(stage, "j" * 64, tmp_path / "a", tmp_path / "src", known=False) is None  # another key
    got = _reuse(stage, "k" * 64, tmp_path / "b", tmp_path / "src", known=False)
    assert got is not None and got["output"] == "dagger.pt" and got["reused_from"] == str(src)
    assert (tmp_path / "b" / "dagger" / "dagger.pt").read_bytes() == b"weights"
    assert json.loads((tmp_path / "b" / "dagger" / "done.json").read_text())["output"] == "dagger.pt"
    assert f"stage dagger reused from {src}" in capsys.readouterr().err


def test_an_eval_output_takes_the_nearest_kept_evaluation_and_says_so(tmp_path, capsys):
    import click

    from vacc.recipes import load_recipe
    from vacc.reproduce import _kept_evaluation

    stage = load_recipe("ice-eco").stage("mid10")
    (tmp_path / "evals").mkdir()
    with pytest.raises(click.ClickException, match="stage mid10: output eval:25000, but .* holds no kept evaluation"):
        _kept_evaluation(stage, tmp_path, 25000)
    for step in (20110, 24990, 25030, 30000):
        (tmp_path / "evals" / f"{step}.pt").write_bytes(b"")
    assert _kept_evaluation(stage, tmp_path, 25000).name == "24990.pt"  # the nearest
    (tmp_path / "evals" / "25010.pt").write_bytes(b"")
    assert _kept_evaluation(stage, tmp_path, 25000).name == "25010.pt"  # as near: the later
    (tmp_path / "evals" / "25000.pt").write_bytes(b"")
    assert _kept_evaluation(stage, tmp_path, 25000).name == "25000.pt" and capsys.readouterr().err.count("took the nearest") == 2


def test_a_swa_output_is_the_even_mean_of_the_evaluations_kept_from_its_step_on(tmp_path, capsys):
    import click

    from agent_client.rl.checkpoint import average_policies
    from vacc.recipes import load_recipe
    from vacc.reproduce import _tail_mean, weights_sha256

    stage = load_recipe("ice-force").stage("long")
    (tmp_path / "evals").mkdir()
    for step, model in ((90, "ice-gap"), (120, "ice-force"), (250, "ice-gap")):
        shutil.copy(ROOT / "models" / f"{model}.pt", tmp_path / "evals" / f"{step}.pt")
    with pytest.raises(click.ClickException, match="stage long: output swa:300, but .* holds no kept evaluation from step 300 on"):
        _tail_mean(stage, tmp_path, 300)
    assert _tail_mean(stage, tmp_path, 200).name == "250.pt"  # one kept: itself
    average_policies([tmp_path / "evals" / "120.pt", tmp_path / "evals" / "250.pt"], tmp_path / "want.pt")
    for _ in range(2):  # a mean left by a killed stage is made again
        assert weights_sha256(_tail_mean(stage, tmp_path, 100)) == weights_sha256(tmp_path / "want.pt")
    assert "the mean of 2 kept evaluations, steps 120-250" in capsys.readouterr().err


@pytest.mark.slow
def test_a_stage_on_other_kernels_goes_on_in_a_fresh_process(tmp_path):
    """One chain may mix kernels (ice-gap's from-scratch stage was made on AVX2, its safety
    fine-tune on AVX-512); torch fixes its kernels at its first computation, so the run starts
    itself again with the stage's, keeping the stages it finished."""
    recipe = tmp_path / "mixed.toml"
    # every stage on the recipe's AVX2 but ev-force, on this CPU's own kernels
    plain = "".join(line for line in EV_FORCE_CHAIN.read_text().splitlines(True) if not line.startswith("cpu_path = "))
    recipe.write_text(plain.replace('name = "ev-force"\nkind = "train"\n', 'name = "ev-force"\nkind = "train"\ncpu_path = "native"\n'))
    native = subprocess.run([sys.executable, "-c", "import torch; print(torch.backends.cpu.get_cpu_capability())"], capture_output=True, text=True, check=True).stdout.strip()
    proc = _reproduce(str(recipe), tmp_path / "run")
    out = _finish(proc)
    assert proc.returncode == 0, out[-2000:]
    kernels = {name: json.loads((tmp_path / "run" / name / "done.json").read_text())["host"]["kernels"] for name in ("gap-scratch", "ev-gap", "ev-force", "mix")}
    pinned = "DEFAULT" if native == "DEFAULT" else "AVX2"
    assert kernels == {"gap-scratch": pinned, "ev-gap": pinned, "ev-force": native, "mix": pinned}, kernels
    paths = {name: json.loads((tmp_path / "run" / name / "done.json").read_text())["cpu_path"] for name in ("gap-scratch", "ev-force", "mix")}
    assert paths == {"gap-scratch": "avx2", "ev-force": "native", "mix": "avx2"}, paths
    # the recipe now names other kernels for a finished stage: kept, and said so
    recipe.write_text(plain)
    out = _finish(_reproduce(str(recipe), tmp_path / "run"))
    assert "stage ev-force was made on native kernels, not avx2: kept" in out and "stage gap-scratch was made" not in out, out[-2000:]


def _check_smoke_run(source: str, folder: Path, returncode: int, out: str) -> None:
    from vacc.recipes import load_recipe

    assert returncode == 0, out[-2000:]
    recipe = load_recipe(source)
    name = recipe.name
    model = torch.load(folder / f"{name}.pt", weights_only=True)
    made = model["lineage"]["recipe"]
    assert made["name"] == name and len(made["digest"]) == 64 and made["stage"] and made["smoke"]
    report = json.loads((folder / "gates" / "gates.json").read_text())
    assert report["quick"] and report["checks"]
    measured = {(m["gate"], m["what"]) for m in report["measures"]}  # beside the checks, for vacc seeds
    for where in ("tests", "random"):
        assert {(where, w) for w in ("mean gap RMSE (m)", "mean ISO jerk share", "energy / the ACC's")} <= measured, measured
    assert ("safety", "closest gap (m)") in measured
    # the gates drive on the recipe's kernels whatever the last stage's (ev-force's: AVX-512)
    assert report["cpu_path"] == recipe.cpu_path, report["cpu_path"]
    if recipe.cpu_path == "avx2":
        assert report["kernels"] != "AVX512"  # pinned (DEFAULT: a CPU without AVX2)
    for stage_dir in (p for p in folder.iterdir() if (p / "done.json").is_file()):
        done = json.loads((stage_dir / "done.json").read_text())
        assert done["stage"] == stage_dir.name and all(len(p["sha256"]) == 64 for p in done["parents"])
        assert done["host"]["cores"] >= 1
        if done["kind"] == "train" and (recipe.stage(stage_dir.name).cpu_path or recipe.cpu_path) == "avx2":
            assert done["host"]["kernels"] != "AVX512"  # pinned to AVX2 (DEFAULT: a CPU without it)
        if done["kind"] == "train":  # its time is its run's, from the scalars (the smoke run: one session)
            logged = max(float(r["wall_s"]) for r in csv.DictReader(open(stage_dir / "run" / "scalars.csv")))
            assert done["wall_s"] == pytest.approx(logged, abs=0.05) and logged > 0
            assert not list((stage_dir / "run").glob("replay*.npz"))  # only a resume reads it
    # the wall-clock per stage and in all, recorded and printed
    timing = json.loads((folder / "timing.json").read_text())
    assert any(v["kind"] == "train" for v in timing["stages"].values())
    assert "wall-clock: " in out and f"total {duration(timing['total_s'])} on " in out and " cores, " in out
    # a smoke run is never compared bit for bit
    assert json.loads((folder / "identity.json").read_text())["compared"] is False and "bit for bit: not compared (--smoke)" in out


@pytest.mark.slow
@pytest.mark.parametrize("name", RECIPES)
def test_smoke_reproduce_runs_every_stage_and_the_gates(name, tmp_path):
    proc = _reproduce(name, tmp_path)
    out = _finish(proc)
    _check_smoke_run(name, tmp_path, proc.returncode, out)


@pytest.mark.slow
def test_a_reproduce_killed_mid_stage_resumes_to_the_same_model(tmp_path):
    """ev-force's smoke run, checked as every recipe's is, then the same killed half-way, its
    folder moved, and resumed there."""
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    proc = _reproduce(SHARED, whole)
    out = _finish(proc)
    _check_smoke_run(SHARED, whole, proc.returncode, out)
    proc = _reproduce(SHARED, killed)
    latest = killed / "ev-gap" / "run" / "latest.pt"  # the second stage has checkpointed: it is half-way
    deadline = time.monotonic() + 300
    while not latest.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (killed / "ev-gap" / "done.json").exists()
    assert list((killed / "ev-gap" / "run").glob("replay*.npz"))  # kept while the stage can resume
    killed = killed.rename(tmp_path / "moved")  # the stage began from killed/gap-scratch/gap-scratch.pt
    proc = _reproduce(SHARED, killed)
    out = _finish(proc)
    assert proc.returncode == 0, out[-2000:]
    a = torch.load(whole / "ev-force.pt", weights_only=True)
    b = torch.load(killed / "ev-force.pt", weights_only=True)
    assert a["model"].keys() == b["model"].keys()
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    assert a["lineage"] == b["lineage"]


@pytest.mark.slow
def test_a_tail_replicate_reuses_the_stages_before_it_and_a_stage_made_otherwise_is_refused(tmp_path):
    """--seed 1 --reseed-from ev-force --reuse A: ev-force's first two stages are copied from
    the seed-0 run A (the same options, seed and parents), its last two run at replicate 1's
    seeds. A folder holding a stage made at another seed is refused, not run over."""
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    proc = _reproduce(SHARED, a)
    out = _finish(proc)
    assert proc.returncode == 0, out[-2000:]
    proc = _reproduce(SHARED, b, "--seed", "1", "--reseed-from", "ev-force", "--reuse", str(a))
    out = _finish(proc)
    assert proc.returncode == 0, out[-2000:]
    done = {run: {n: json.loads((run / n / "done.json").read_text()) for n in ("gap-scratch", "ev-gap", "ev-force", "mix")} for run in (a, b)}
    for name in ("gap-scratch", "ev-gap"):
        assert f"stage {name} reused from {a / name}" in out and f"{name} {duration(json.loads((a / 'timing.json').read_text())['stages'][name]['wall_s'])} (reused)" in out
        assert done[b][name]["weights_sha256"] == done[a][name]["weights_sha256"] and not (b / name / "run").exists()
        # stamped as run b would have made it (its replicate), the record naming the file as it now is
        lineage = read_checkpoint(b / name / f"{name}.pt")["lineage"]
        assert lineage["recipe"]["seed"] == 1 and read_checkpoint(a / name / f"{name}.pt")["lineage"]["recipe"]["seed"] == 0
        assert done[b][name]["seed"] == 1 and done[b][name]["sha256"] == file_sha256(b / name / f"{name}.pt")
    for name in ("ev-force", "mix"):
        assert f"stage {name} reused" not in out and done[b][name]["weights_sha256"] != done[a][name]["weights_sha256"]
        assert json.loads((b / name / "run" / "config.json").read_text())["seed"] == json.loads((a / name / "run" / "config.json").read_text())["seed"] + SEED_STRIDE
    for name in ("gap-scratch", "ev-gap", "ev-force"):
        shutil.copytree(a / name, c / name)
    before = (c / "ev-force" / "ev-force.pt").read_bytes()
    proc = _reproduce(SHARED, c, "--seed", "1", "--reseed-from", "ev-force")
    out = _finish(proc)
    assert proc.returncode == 1 and f"{c / 'ev-force'} holds a stage made with other options, seed or parents than this run's ev-force" in out, out[-2000:]
    assert (c / "ev-force" / "ev-force.pt").read_bytes() == before and not (c / "mix").exists()


@pytest.mark.slow
def test_a_shipped_stage_takes_the_file_whose_weights_the_recipe_names_and_refuses_another(tmp_path):
    """ice-eco-ac starts from the shipped ice-eco: its lineage names that file's weights; a
    models folder whose ice-eco.pt has other weights is refused in one line, naming both."""
    from agent_client.rl.checkpoint import read_checkpoint, save_policy
    from agent_client.rl.config import Config
    from agent_client.rl.network import QNetwork
    from vacc.recipes import load_recipe

    shipped = load_recipe("ice-eco-ac").stage("ice-eco").options
    out = _finish(_reproduce("ice-eco-ac", tmp_path / "ok"))
    lineage = read_checkpoint(tmp_path / "ok" / "ice-eco" / "ice-eco.pt")["lineage"]
    assert {"sha256": shipped["weights_sha256"], "digest_of": "weights", "path": "models/ice-eco.pt", "role": "shipped"} in lineage["parents"], out
    (tmp_path / "models").mkdir()
    save_policy(QNetwork(), Config(), tmp_path / "models" / "ice-eco.pt")
    proc = subprocess.run([sys.executable, "-m", "vacc", "reproduce", "ice-eco-ac", "--out", str(tmp_path / "other"), "--smoke", "--quiet"],
                          cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT), "VACC_MODELS": str(tmp_path / "models")},
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert "stage ice-eco" in line and shipped["weights_sha256"] in line and "ice-eco.pt" in line, proc.stderr
