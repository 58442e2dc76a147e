"""`vacc reproduce`: run a recipe's stages in order, then its gates.

Each stage runs in ``DIR/<stage>/`` and writes one checkpoint, ``DIR/<stage>/<stage>.pt``,
that records its lineage (``ckpt["lineage"]``: the recipe, its digest, the stage, and its
parents' SHA-256 (of their weights, with their paths relative to the output folder). A finished stage writes ``done.json`` with that file's
SHA-256 and is skipped when the same command runs again; a train stage stopped half-way
(Ctrl-C, kill -9) continues from its run folder's ``latest.pt`` with the trainer's own
bit-exact resume; a surgery stage (average, decide, narrow, export) is quick and simply
runs again. The run ends with ``DIR/<model>.pt`` and the gate report (``DIR/gates/``).

Bit for bit: at the recipe's own seed, each stage with ``known_weights`` and the model itself
(against the shipped ``models/<model>.pt``, where there is one) are compared by the SHA-256 of
their weights, written to ``DIR/identity.json`` and printed in one line (:func:`identity`).

Seeds: ``--seed N`` moves every train stage's seed by :data:`SEED_STRIDE` times
(N minus the recipe's seed): the recipe's own seed gives its written seeds, and every
other N a distinct, equally written-out set. ``--reseed-from STAGE`` (by default the recipe's
``reseed_from``, else the first stage) moves only the seeds of STAGE and the stages after it
(a replicate of a chain's tail), and ``--reuse DIR`` copies the
finished stages of another run that are the same stage: the same options, seed and parents
(:func:`stage_key`, recorded in each ``done.json``; a record older than keys, where it made the
stage's ``known_weights``). A ``done.json`` whose key differs from the stage's is refused, never run over.

``--smoke`` runs every stage for a few dozen steps (:func:`smoke_config`) and the gates
in their quick mode: it checks that a recipe still runs, not what it makes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from agent_client.errors import ClientError
from agent_client.rl.checkpoint import (
    POLICY_FIELDS,
    atomic_save,
    average_policies,
    checkpoint_config,
    digest,
    export_policy,
    file_sha256,
    narrow_policy,
    read_checkpoint,
    with_decision,
)
from agent_client.rl.config import Config, config_dict, single_stream_only
from agent_client.rl.scalars import logged_wall_s
from agent_client.rl.stop import STOP, stop_exit_code, stop_handlers
from vacc.host import CPU_PATHS, PINNED, describe, label, pinned_path, use_cpu_path
from vacc.paths import models_dir
from vacc.recipes import (
    Recipe,
    RecipeError,
    Stage,
    keyed_options,
    load_recipe,
    stage_config,
    stage_refs,
)

__all__ = ["SEED_STRIDE", "SMOKE", "file_sha256", "weights_sha256", "shifted_seed", "smoke_config", "stamp_lineage", "run_stage", "reproduce", "reproduce_command",
           "timing_line", "duration", "identity", "identity_line"]

SEED_STRIDE = 10_000
"""--seed N adds SEED_STRIDE * (N - recipe seed) to each train stage's seed."""

SMOKE = {"total_steps": 40, "learning_starts": 20, "exploration_steps": 25, "episode_seconds": 3.0, "eval_seconds": 0.5,
         "eval_every": 0, "checkpoint_every": 20, "buffer_size": 2_000, "target_sync_every": 30, "teacher_steps": 40,
         "batch_size": 8, "bc_steps": 10}  # fmt: skip
"""What --smoke sets in every train stage (each value at most the recipe's), and one evaluation trajectory."""


def weights_sha256(path: Path) -> str:
    """SHA-256 of a checkpoint's weights alone (:func:`~agent_client.rl.checkpoint.digest` of
    its ``model``): what a lineage names a parent by, the same wherever the run folder is
    (the file itself records paths)."""
    return digest({"model": read_checkpoint(path)["model"]})


def policy_sha256(path: Path) -> str:
    """SHA-256 of a checkpoint's policy: its weights and the settings that decide how it sees
    and acts (:data:`~agent_client.rl.checkpoint.POLICY_FIELDS`, the decision rule among them),
    so that the same weights under another rule count as another model."""
    ckpt = read_checkpoint(path)
    cfg = config_dict(checkpoint_config(ckpt, path))
    return digest({"model": ckpt["model"], "policy": {k: cfg[k] for k in POLICY_FIELDS}})


def shifted_seed(seed: int, recipe: Recipe, replicate: int) -> int:
    """A train stage's seed for ``--seed replicate`` (see :data:`SEED_STRIDE`)."""
    return seed + SEED_STRIDE * (replicate - recipe.seed)


def replicate_of(recipe: Recipe, stage: Stage, opts: dict[str, Any]) -> int:
    """The replicate a stage runs as: ``--seed``'s, or the recipe's own seed for a stage
    before ``--reseed-from``'s (else the recipe's ``reseed_from``)."""
    start = opts.get("reseed_from") or recipe.reseed_from  # absent: the recipe's (identity's callers pass the seed and --smoke only)
    if start is not None and recipe.stages.index(stage) < recipe.stages.index(recipe.stage(start)):
        return recipe.seed
    return int(opts["seed"])


def stage_key(recipe: Recipe, stage: Stage, opts: dict[str, Any], parents: list[str]) -> str:
    """What makes a stage's output: its kind and options, the replicate it runs as (a train
    stage's), --smoke and its parents' weights (SHA-256), hashed. Not its name, note or
    kernels, nor the recipe's other stages, so the same stage in another recipe has the same key."""
    replicate = replicate_of(recipe, stage, opts) if stage.kind == "train" else None
    return digest({"kind": stage.kind, "options": keyed_options(stage.options), "seed_shift": None if replicate is None else replicate - recipe.seed,
                   "smoke": bool(opts["smoke"]), "parents": parents})  # fmt: skip


def smoke_config(cfg: Config) -> Config:
    """``cfg`` cut to a few dozen steps (:data:`SMOKE`), evaluated on its first trajectory."""
    small: dict[str, Any] = {k: (min(getattr(cfg, k), v) if getattr(cfg, k) is not None else v) for k, v in SMOKE.items()}
    return dataclasses.replace(cfg, **small, eval_trajectories=cfg.eval_trajectories[:1])


def stamp_lineage(path: Path, lineage: dict[str, Any]) -> None:
    """Record ``lineage`` in the checkpoint ``path`` (``ckpt["lineage"]``), rewritten atomically
    with its digest; its loaders ignore the entry."""
    ckpt = read_checkpoint(path)
    ckpt["lineage"] = lineage
    atomic_save({k: v for k, v in ckpt.items() if k != "sha256"}, path)


def _train_stage(recipe: Recipe, stage: Stage, sdir: Path, inputs: dict[str, str], opts: dict[str, Any]) -> Path:
    """Run (or resume) a train stage in ``sdir/run``; returns the policy it keeps."""
    from agent_client.rl.cli import run_files  # the trainer's own list of its files

    cfg = stage_config(stage, inputs)
    cfg = dataclasses.replace(cfg, seed=shifted_seed(cfg.seed, recipe, replicate_of(recipe, stage, opts)))
    if opts["smoke"]:
        cfg = smoke_config(cfg)
    if opts["servers"] > 1 and single_stream_only(dataclasses.replace(cfg, servers=1)) is None:
        cfg = dataclasses.replace(cfg, servers=opts["servers"])
    run = sdir / "run"
    resume = (run / "latest.pt").is_file()
    if resume:
        cfg = _as_begun(cfg, run)
    if not resume:
        for old in run_files(run):  # stopped before its first checkpoint: start it afresh
            old.unlink()
    run.mkdir(parents=True, exist_ok=True)
    if cfg.servers > 1 or opts["ray"]:
        from agent_client.rl.distributed import train_distributed

        summary = train_distributed(cfg, run, resume=resume, progress=opts["progress"], use_ray=opts["ray"])
    else:
        from agent_client.rl.train import train

        summary = train(cfg, run, resume=resume, progress=opts["progress"])
    if summary.get("stopped"):
        raise KeyboardInterrupt
    output = stage.options["output"]
    if output.startswith("eval:") and not opts["smoke"]:
        return _kept_evaluation(stage, run, int(output.removeprefix("eval:")))
    if output.startswith("swa:") and not opts["smoke"]:
        return _tail_mean(stage, run, int(output.removeprefix("swa:")))
    if output == "best" and (run / "best.pt").is_file():
        return run / "best.pt"
    if output == "best" and not opts["smoke"]:
        raise click.ClickException(f"stage {stage.name}: no evaluation passed, so {run / 'best.pt'} was never written")
    return run / "latest.pt"  # exported as a policy by the caller (--smoke: for any output)


def _as_begun(cfg: Config, run: Path) -> Config:
    """``cfg`` with the ``init_from`` its run began with, where only the folder around it moved
    (the same ``<stage>/<stage>.pt``): a run folder moved elsewhere resumes. The start is read at
    a run's beginning only, and its weights are the stage key's, so nothing the run makes
    changes. Not where a resume reads it again (an actor-critic's student)."""
    if cfg.bc_steps > 0 or cfg.bc_weight > 0.0:
        return cfg
    try:
        then = json.loads((run / "config.json").read_text()).get("init_from")
    except (OSError, ValueError):
        return cfg  # the trainer's own check says what is wrong
    now = cfg.init_from
    if isinstance(now, str) and isinstance(then, str) and now != then and Path(now).parts[-2:] == Path(then).parts[-2:]:
        return dataclasses.replace(cfg, init_from=then)
    return cfg


def _kept_evaluation(stage: Stage, run: Path, step: int) -> Path:
    """The evaluation ``eval:STEP`` names, or, where a rebuild that is not bit for bit ended its
    episodes elsewhere (evaluations wait for an episode's end), the kept one nearest it, said in a line.

    Raises:
        click.ClickException: the run kept no evaluation at all.
    """
    exact = run / "evals" / f"{step}.pt"
    if exact.is_file():
        return exact
    kept = sorted((abs(int(p.stem) - step), -int(p.stem), p) for p in (run / "evals").glob("*.pt") if p.stem.isdigit())
    if not kept:
        raise click.ClickException(f"stage {stage.name}: output eval:{step}, but {run / 'evals'} holds no kept evaluation (keep_evals must be true)")
    nearest = kept[0][2]
    click.echo(f"vacc reproduce: stage {stage.name}: no evaluation at step {step}; took the nearest, at step {nearest.stem} (this run is not the recorded one bit for bit)", err=True)
    return nearest


def _tail_mean(stage: Stage, run: Path, step: int) -> Path:
    """``swa:STEP``: the even mean of the evaluations kept from ``STEP`` on, in step order
    (stochastic weight averaging over the run's tail), written to ``run/swa.pt``.

    Raises:
        click.ClickException: the run kept no evaluation from ``STEP`` on.
    """
    kept = sorted((int(p.stem), p) for p in (run / "evals").glob("*.pt") if p.stem.isdigit() and int(p.stem) >= step)
    if not kept:
        raise click.ClickException(f"stage {stage.name}: output swa:{step}, but {run / 'evals'} holds no kept evaluation from step {step} on (keep_evals must be true)")
    if len(kept) == 1:
        return kept[0][1]
    (run / "swa.pt").unlink(missing_ok=True)  # a mean written before a kill: made again, the same
    average_policies([str(p) for _, p in kept], run / "swa.pt", [1.0] * len(kept))
    click.echo(f"vacc reproduce: stage {stage.name}: the mean of {len(kept)} kept evaluations, steps {kept[0][0]}-{kept[-1][0]}", err=True)
    return run / "swa.pt"


def _surgery_stage(stage: Stage, inputs: dict[str, str], dst: Path) -> None:
    """Run an average, decide, narrow, export or shipped stage into ``dst``.

    Raises:
        ValueError: a shipped model that is not there, or whose weights are not the recipe's.
    """
    o = stage.options
    if stage.kind == "shipped":
        src = models_dir() / f"{o['model']}.pt"
        if not src.is_file():
            raise ValueError(f"{src}: no such shipped model")
        if (got := weights_sha256(src)) != o["weights_sha256"]:
            raise ValueError(f"{src}: its weights' SHA-256 is {got}, the recipe's {o['weights_sha256']}: the recipe was written for another file")
        export_policy(str(src), dst)
    elif stage.kind == "average":
        average_policies([inputs[r] for r in stage_refs(stage)], dst, [float(w) for w in o["weights"]])
    elif stage.kind == "decide":
        with_decision(inputs[stage_refs(stage)[0]], dst, o["decision"], float(o["temperature"]), float(o["brake_share"]),
                      float(o["deadband"]), float(o["smoothing"]), int(o["brake_confirm"]), int(o["full_brake_confirm"]))  # fmt: skip
    elif stage.kind == "narrow":
        narrow_policy(inputs[stage_refs(stage)[0]], dst, tuple(o["conv_channels"]), int(o["hidden"]))
    else:
        export_policy(inputs[stage_refs(stage)[0]], dst)


def _key(recipe: Recipe, stage: Stage, opts: dict[str, Any], done: dict[str, dict[str, Any]]) -> str:
    """:func:`stage_key` of ``stage``, its parents' weights taken from their ``done`` records."""
    return stage_key(recipe, stage, opts, [done[name]["weights_sha256"] for name in stage_refs(stage)])


def _done_record(out: Path, stage: Stage, key: str) -> dict[str, Any] | None:
    """A finished stage's ``done.json``, where it matches the file it made; else None.

    Raises:
        click.ClickException: it records another stage key (other options, seed or parents;
            a record from before keys were written is taken as it is).
    """
    record_file, dst = out / stage.name / "done.json", out / stage.name / f"{stage.name}.pt"
    if record_file.is_file() and dst.is_file():
        record = json.loads(record_file.read_text())
        if record.get("sha256") == file_sha256(dst):
            if record.get("stage_key", key) != key:
                raise click.ClickException(f"{out / stage.name} holds a stage made with other options, seed or parents than this run's {stage.name}: remove it or give a new --out")
            return dict(record)
    return None


def _reuse(stage: Stage, key: str, out: Path, source: Path, known: bool) -> dict[str, Any] | None:
    """Copy ``source``'s finished stage that is ``stage`` into ``out``; its record, else None.

    The stage of the same name is looked at first, then every other (keys leave names out, so
    a stage another recipe names otherwise is found). Where this stage is compared with its
    ``known_weights`` (``known``), a record that made exactly those weights is this stage
    whatever its key: a record from before keys were written, or one whose key counts options
    that change nothing (ev-force's ``ev-gap`` is ev-gap's ``base`` with another thread count
    and eco weights its gap reward never reads)."""
    same_name = source / stage.name
    for sdir_src in [same_name, *sorted(d for d in source.iterdir() if d.is_dir() and d != same_name)]:
        record_file = sdir_src / "done.json"
        if not record_file.is_file():
            continue
        record = json.loads(record_file.read_text())
        src = sdir_src / str(record.get("output", f"{sdir_src.name}.pt"))
        if not src.is_file() or record.get("sha256") != file_sha256(src):
            continue
        made_known = known and record.get("weights_sha256") == stage.known_weights
        if record.get("stage_key") != key and not made_known:
            continue
        record["stage_key"] = key
        sdir = out / stage.name
        sdir.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, sdir / f"{stage.name}.pt")
        record["output"] = f"{stage.name}.pt"
        record["reused_from"] = str(sdir_src)
        (sdir / "done.json").write_text(json.dumps(record, indent=1) + "\n")
        why = "it made this stage's known weights" if made_known else "the same options, seed and parents"
        click.echo(f"vacc reproduce: stage {stage.name} reused from {sdir_src} ({why})", err=True)
        return dict(record)
    return None


def _pin_kernels(path: str, reexec: Callable[[dict[str, str]], None] | None, progress: bool, what: str = "the next stage runs") -> None:
    """Run ``what`` (the next train stage, or the gates) on :data:`~vacc.host.CPU_PATHS` ``[path]``: pinned in this process
    while torch has computed nothing, else in a fresh one (``reexec``: this command again, whose
    finished stages are kept), since torch fixes its kernels at its first computation.

    Raises:
        click.ClickException: a fresh process is needed and ``reexec`` is None.
    """
    current = os.environ.get(PINNED)
    if current == path:
        return
    if current is None:
        try:
            use_cpu_path(path)
            return
        except RuntimeError:
            pass
    if reexec is None:
        raise click.ClickException(f"{what} on {path} kernels, this process on {current or 'others'}: run vacc reproduce again")
    if progress:
        click.echo(f"vacc reproduce: {what} on {path} kernels: going on in a fresh process (the finished stages are kept)", err=True)
    env = {k: v for k, v in os.environ.items() if not any(k in p for p in CPU_PATHS.values())}
    reexec({**env, **CPU_PATHS[path], PINNED: path})


def run_stage(recipe: Recipe, stage: Stage, out: Path, done: dict[str, dict[str, Any]], opts: dict[str, Any], key: str) -> dict[str, Any]:
    """Run one stage whose ``done.json`` is not there (:func:`_done_record`), its
    :func:`stage_key` ``key``; returns its record.

    Raises:
        click.ClickException: the stage failed.
    """
    sdir = out / stage.name
    dst = sdir / f"{stage.name}.pt"
    sdir.mkdir(parents=True, exist_ok=True)
    dst.unlink(missing_ok=True)  # a stage stopped after its write and before done.json: made again, the same
    inputs = {name: str(out / name / f"{name}.pt") for name in stage_refs(stage)}
    t0 = time.perf_counter()
    try:
        if stage.kind == "train":
            export_policy(_train_stage(recipe, stage, sdir, inputs, opts), dst)
        else:
            _surgery_stage(stage, inputs, dst)
    except (ClientError, ValueError) as exc:
        raise click.ClickException(f"stage {stage.name}: {exc}") from None
    # a train stage's time over all its sessions (its scalars restart with each resume); a surgery stage's now
    try:
        wall_s: float | None = logged_wall_s(sdir / "run") if stage.kind == "train" else time.perf_counter() - t0
    except (ClientError, ValueError):  # a scalars file it cannot read: the time unknown, the stage done
        wall_s = None
    made = _stamp(recipe, stage, dst, done, opts)
    record = {**made, "kind": stage.kind, "output": dst.name, "sha256": file_sha256(dst), "weights_sha256": weights_sha256(dst),
              "wall_s": None if wall_s is None else round(wall_s, 1), "host": describe(), "stage_key": key}  # fmt: skip
    if stage.kind == "train":
        record["cpu_path"] = pinned_path()  # the path asked (host.kernels: torch's own name for it)
    (sdir / "done.json").write_text(json.dumps(record, indent=1) + "\n")
    if stage.kind == "train" and not opts.get("keep_replay"):  # only a resume reads it: GBs a stage
        for buffer in (sdir / "run").glob("replay*.npz"):
            buffer.unlink()
    return record


def _stamp(recipe: Recipe, stage: Stage, dst: Path, done: dict[str, dict[str, Any]], opts: dict[str, Any]) -> dict[str, Any]:
    """Stamp ``dst`` with this run's lineage; returns it as a record's fields (recipe, stage, parents).

    The checkpoint layout's lineage (vacc checkpoint info reads it): parents by the SHA-256 of
    their weights (their files also record paths) and by their paths relative to the output
    folder, so that a run records the same lineage in any folder."""
    parents = [{"sha256": done[name]["weights_sha256"], "digest_of": "weights", "path": f"{name}/{name}.pt", "role": name} for name in stage_refs(stage)]
    if stage.kind == "shipped":  # a file of the repository, which its own recipe rebuilds
        parents.append({"sha256": stage.options["weights_sha256"], "digest_of": "weights", "path": f"models/{stage.options['model']}.pt", "role": "shipped"})
    made = {"name": recipe.name, "digest": recipe.digest, "stage": stage.name, "seed": opts["seed"], "smoke": opts["smoke"]}
    stamp_lineage(dst, {"stage": stage.kind, "parents": parents, "recipe": made})
    return {**made, "parents": parents}


def _restamp(recipe: Recipe, stage: Stage, out: Path, done: dict[str, dict[str, Any]], opts: dict[str, Any], record: dict[str, Any]) -> dict[str, Any]:
    """A stage copied by --reuse, stamped as this run would have made it: its lineage names this
    recipe, stage and replicate (another recipe's run or another name for the same stage may have
    made it); the weights are untouched. Returns its record, rewritten to ``done.json``."""
    dst = out / stage.name / f"{stage.name}.pt"
    record = {**record, **_stamp(recipe, stage, dst, done, opts), "sha256": file_sha256(dst)}
    (out / stage.name / "done.json").write_text(json.dumps(record, indent=1) + "\n")
    return record


def _check_folder(recipe: Recipe, out: Path, opts: dict[str, Any]) -> None:
    """Write ``out/reproduce.json``, or check that the folder is this recipe's run with these options.

    Raises:
        click.ClickException: ``out`` holds another recipe's or another seed's run.
    """
    mine = {"recipe": recipe.name, "recipe_digest": recipe.digest, "seed": opts["seed"], "smoke": opts["smoke"], "cpu_path": opts["cpu_path"],
            "reseed_from": opts["reseed_from"]}  # fmt: skip
    marker = out / "reproduce.json"
    if marker.is_file():
        theirs = json.loads(marker.read_text())
        theirs.setdefault("cpu_path", "native")  # a run begun before the kernels were pinned
        theirs.setdefault("reseed_from", None)
        differ = [k for k in mine if theirs.get(k) != mine[k]]
        if differ:
            raise click.ClickException(f"{out} holds a run with another {differ[0]} ({theirs.get(differ[0])!r}, here {mine[differ[0]]!r}): give a new --out")
        return
    out.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps(mine, indent=1) + "\n")


def reproduce(recipe: Recipe, out: Path, *, seed: int | None = None, servers: int = 1, use_ray: bool = False,
              smoke: bool = False, progress: bool = True, jobs: int = 2, cpu_path: str | None = None,
              reseed_from: str | None = None, reuse: Path | None = None, keep_replay: bool = False,
              reexec: Callable[[dict[str, str]], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Run every stage of ``recipe`` into ``out``, copy the last one's policy to
    ``out/<model>.pt`` and check it against the gates (``out/gates/gates.json``).
    Each train stage runs on ``cpu_path``'s kernels (:data:`vacc.host.CPU_PATHS`; None: the
    stage's own ``cpu_path``, else the recipe's); where they change, ``reexec`` starts this run
    again in a fresh process with them (see :func:`_pin_kernels`). ``reseed_from`` keeps the
    recipe's own seeds before that stage; ``reuse`` is another run's folder whose finished
    stages are copied where they are the same (:func:`stage_key`). A finished train stage's
    replay buffer is removed unless ``keep_replay``.

    Returns:
        The gate report (:func:`vacc.gates.evaluate_gates`).

    Raises:
        click.ClickException: a stage failed, ``reseed_from`` names no stage, ``reuse`` is no
            folder, or ``out`` holds another run.
    """
    from vacc.gates import evaluate_gates

    if reseed_from is not None and reseed_from not in [s.name for s in recipe.stages]:
        raise click.ClickException(f"--reseed-from {reseed_from}: {recipe.name} has no such stage (it has {', '.join(s.name for s in recipe.stages)})")
    if reuse is not None and not reuse.is_dir():
        raise click.ClickException(f"--reuse {reuse}: no such folder")
    opts = {"seed": recipe.seed if seed is None else seed, "servers": servers, "ray": use_ray, "smoke": smoke, "progress": progress,
            "cpu_path": recipe.cpu_path if cpu_path is None else cpu_path, "reseed_from": reseed_from or recipe.reseed_from, "reuse": reuse,
            "keep_replay": keep_replay}  # fmt: skip
    for stage in recipe.stages:
        written = stage.options.get("seed") if stage.kind == "train" else None
        if isinstance(written, int) and shifted_seed(written, recipe, replicate_of(recipe, stage, opts)) < 0:
            raise click.ClickException(f"--seed {opts['seed']}: stage {stage.name}'s seed would be {written} + {SEED_STRIDE:,} x ({opts['seed']} - {recipe.seed}), "
                                       f"below 0 ({recipe.name}'s seeds are written for replicate {recipe.seed}): give --seed >= {recipe.seed} or a later --reseed-from")
    _check_folder(recipe, out, opts)
    done: dict[str, dict[str, Any]] = {}
    for i, stage in enumerate(recipe.stages, 1):
        if STOP.is_set():  # a signal between two stages, or in a surgery stage
            raise KeyboardInterrupt
        if progress:
            click.echo(f"vacc reproduce {recipe.name}: stage {i}/{len(recipe.stages)} {stage.name} ({stage.kind})", err=True)
        path = cpu_path or stage.cpu_path or recipe.cpu_path  # --cpu-path, else the stage's, else the recipe's
        key = _key(recipe, stage, opts, done)
        record = _done_record(out, stage, key)
        if record is None and reuse is not None:
            record = _reuse(stage, key, out, reuse, bool(stage.known_weights) and _compared(recipe, stage, opts))
            if record is not None:
                record = _restamp(recipe, stage, out, done, opts, record)
        if stage.kind == "train" and record is not None and record.get("cpu_path", path) != path:  # said even when quiet
            click.echo(f"vacc reproduce: stage {stage.name} was made on {record['cpu_path']} kernels, not {path}: kept (remove {out / stage.name} to make it again)", err=True)
        if stage.kind == "train" and record is None:
            _pin_kernels(path, reexec, progress)
            kernels = describe(with_gpu=False)["kernels"]
            if progress and path != "native" and kernels != path.upper():
                click.echo(f"vacc reproduce: this CPU runs {kernels}, not {path.upper()}: stage {stage.name} will not make the known weights bit for bit", err=True)
        done[stage.name] = record if record is not None else run_stage(recipe, stage, out, done, opts, key)
        if progress and stage.known_weights and _compared(recipe, stage, opts):  # hours before the end's line
            same = done[stage.name]["weights_sha256"] == stage.known_weights
            click.echo(f"vacc reproduce {recipe.name}: stage {stage.name}'s weights {'are identical to' if same else 'DIFFER from'} the known ones", err=True)
    last = recipe.stages[-1].name
    final = out / f"{recipe.name}.pt"
    shutil.copyfile(out / last / f"{last}.pt", final)
    if STOP.is_set():
        raise KeyboardInterrupt
    _pin_kernels(str(opts["cpu_path"]), reexec, progress, "the gates run")  # the recipe's kernels (or --cpu-path), as `vacc gates` drives them
    t0 = time.perf_counter()
    report = evaluate_gates(recipe, final, out / "gates", quick=smoke, jobs=jobs)
    stages = {name: {"kind": r["kind"], "wall_s": r.get("wall_s"), "host": r.get("host"), "reused": "reused_from" in r} for name, r in done.items()}
    timing = {"stages": stages, "gates_s": round(time.perf_counter() - t0, 1), "gates_host": describe(), "smoke": smoke}
    timing["total_s"] = None if any(v["wall_s"] is None for v in stages.values()) else round(sum(v["wall_s"] for v in stages.values()) + timing["gates_s"], 1)
    (out / "timing.json").write_text(json.dumps(timing, indent=1) + "\n")
    report["timing"] = timing
    report["identity"] = identity(recipe, done, final, opts)
    (out / "identity.json").write_text(json.dumps(report["identity"], indent=1) + "\n")
    return report


def identity(recipe: Recipe, done: dict[str, dict[str, Any]], final: Path, opts: dict[str, Any]) -> dict[str, Any]:
    """Whether a run made the known weights again: each stage with ``known_weights``, and the
    model's policy (:func:`policy_sha256`) against the shipped ``<models>/<name>.pt`` (where there is one). Only the stages run
    at the recipe's own seed (all but a replicate's, or a replicate's before its
    ``--reseed-from``), and not with --smoke; where none is, ``{"compared": False, "why": ...}``."""
    from vacc.paths import models_dir

    checks = [{"what": f"stage {s.name}", "known": s.known_weights, "made": done[s.name]["weights_sha256"]}
              for s in recipe.stages if s.known_weights and _compared(recipe, s, opts)]  # fmt: skip
    shipped = models_dir() / f"{recipe.name}.pt"
    if shipped.is_file() and _compared(recipe, recipe.stages[-1], opts):
        checks.append({"what": f"{final.name} against {shipped}", "known": policy_sha256(shipped), "made": policy_sha256(final)})
    why = _not_compared(recipe, opts)
    if why and not checks:
        return {"compared": False, "why": why, "checks": []}
    for c in checks:
        c["identical"] = c["known"] == c["made"]
    return {"compared": True, "why": "", "checks": checks}


def _compared(recipe: Recipe, stage: Stage, opts: dict[str, Any]) -> bool:
    """Whether ``stage``'s weights are compared with the known ones: not --smoke, and run at the recipe's own seed."""
    return not opts["smoke"] and replicate_of(recipe, stage, opts) == recipe.seed


def _not_compared(recipe: Recipe, opts: dict[str, Any]) -> str:
    """Why a run's weights are not compared with the known ones ("" when they are)."""
    if opts["smoke"]:
        return "--smoke"
    if opts["seed"] != recipe.seed:
        return f"--seed {opts['seed']} is a replicate (the recipe's seed is {recipe.seed})"
    return ""


def identity_line(ident: dict[str, Any]) -> str:
    """``bit for bit: stage scratch identical, stage safety DIFFERS; ...`` in one line."""
    if not ident["compared"]:
        return f"bit for bit: not compared ({ident['why']})"
    if not ident["checks"]:
        return "bit for bit: nothing known to compare with"
    return "bit for bit: " + ", ".join(f"{c['what']} {'identical' if c['identical'] else 'DIFFERS'}" for c in ident["checks"])


def duration(seconds: float) -> str:
    """``3 h 05 min``, ``14 min 10 s`` or ``0.4 s``."""
    if seconds >= 3600:
        return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"
    if seconds >= 60:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{seconds:.1f} s"


def timing_line(timing: dict[str, Any]) -> str:
    """The wall-clock of a run in one line: each stage (one copied by --reuse: its first run's), the gates,
    the total, and the machines."""
    parts = [f"{name} {'?' if v['wall_s'] is None else duration(v['wall_s'])}{' (reused)' if v.get('reused') else ''}" for name, v in timing["stages"].items()]
    hosts = {label(v["host"]) for v in timing["stages"].values() if v["host"]} | {label(timing["gates_host"])}
    total = "?" if timing["total_s"] is None else duration(timing["total_s"])
    return f"wall-clock: {', '.join(parts)}, gates {duration(timing['gates_s'])}; total {total} on {' / '.join(sorted(hosts))}"


def _reexec_command(env: dict[str, str]) -> None:
    """This ``vacc reproduce`` command again, in place of this process (same PID), with ``env``."""
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, "-m", "vacc", *sys.argv[1:]], env)


@click.command("reproduce")
@click.argument("model_or_recipe")
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder of the run: one subfolder per stage, the model, the gates.")
@click.option("--seed", default=None, type=click.IntRange(min=0), help=f"Replicate N: each train stage's seed + {SEED_STRIDE:,} x (N - the recipe's seed). Default: the recipe's seed (its written seeds).")
@click.option("--reseed-from", default=None, metavar="STAGE", help="With --seed: replicate only STAGE and the stages after it; those before keep the recipe's seeds (a chain's tail over seeds). Default: the recipe's reseed_from, else every stage.")
@click.option("--reuse", default=None, type=click.Path(file_okay=False), help="Another run's folder: copy each finished stage of it that is the same here (options, seed, parents) instead of running it.")
@click.option("--servers", default=1, show_default=True, type=click.IntRange(min=1), help="Servers feeding each train stage that the K-stream trainer can run (others run one).")
@click.option("--ray", "use_ray", is_flag=True, help="Run the train stages' servers and actors as Ray actors (vacc[ray]).")
@click.option("--smoke", is_flag=True, help="Every stage for a few dozen steps, the gates in quick mode: checks the recipe runs.")
@click.option("--jobs", default=2, show_default=True, type=click.IntRange(1, 64), help="Gate runs in parallel.")
@click.option("--cpu-path", type=click.Choice(tuple(CPU_PATHS)), default=None,
              help="Every train stage's CPU kernels, and the gates': avx2 (rebuilds agree across x86-64 machines), avx512 (AVX-512's common level) or native (the widest, bit for bit only on the same CPU). Default: each stage's cpu_path, else the recipe's (avx2); the gates on the recipe's.")
@click.option("--keep-replay", is_flag=True, help="Keep each finished train stage's replay buffer (only a resume reads it; GBs a stage).")
@click.option("--quiet", is_flag=True, help="No progress lines.")
def reproduce_command(model_or_recipe: str, out: str, seed: int | None, reseed_from: str | None, reuse: str | None, servers: int, use_ray: bool,
                      smoke: bool, jobs: int, cpu_path: str | None, keep_replay: bool, quiet: bool) -> None:  # fmt: skip
    """Rebuild a model from its recipe (a model name, or recipes/NAME.toml): every stage in
    order into OUT/<stage>/, then OUT/<model>.pt, its gate report and its wall-clock
    (OUT/timing.json). Stopped at any point
    (Ctrl-C, kill -9), the same command continues. Exits 1 if a gate fails (not with --smoke)."""
    from vacc.gates import gate_table

    if servers > 1 and use_ray:
        raise click.UsageError("give --servers K or --ray, not both")
    try:
        recipe = load_recipe(model_or_recipe)
    except RecipeError as exc:
        raise click.ClickException(str(exc)) from None
    with stop_handlers("vacc reproduce", "; the same command continues"):
        try:
            report = reproduce(recipe, Path(out), seed=seed, servers=servers, use_ray=use_ray, smoke=smoke, progress=not quiet, jobs=jobs,
                               cpu_path=cpu_path, reseed_from=reseed_from, reuse=None if reuse is None else Path(reuse),
                               keep_replay=keep_replay, reexec=_reexec_command)  # fmt: skip
        except KeyboardInterrupt:
            click.echo(f"stopped; continue with the same command: vacc reproduce {' '.join(sys.argv[2:])}", err=True)
            raise SystemExit(stop_exit_code()) from None
    click.echo(gate_table(report))
    click.echo(timing_line(report["timing"]))
    click.echo(identity_line(report["identity"]))
    click.echo(f"Wrote {out}/{recipe.name}.pt, {out}/gates/gates.json, {out}/timing.json and {out}/identity.json")
    if not report["passed"] and not smoke:
        raise SystemExit(1)
