"""Checkpoints: one layout for policies and for both trainers' training state.

A checkpoint is a ``torch.save`` dict::

    format   "vacc-ddqn"
    version  2 (1: written before this layout; still read, without a digest)
    kind     "policy" | "training"
    config   the run's Config as builtins
    model    the online network's weights
    sha256   digest of everything else (checked on every load)
    extra    (policy) e.g. the step and evaluation that chose it
    trainer  (training) "single" | "streams"
    target, optimizer, acting (the parallel schedule's acting weights, else absent)
    state    the loop's counters (step, episodes, best score, ...)
    rng      generator states by name, torch's and python's
    replay   the replay file names that go with it
    lineage  what made it (absent in files written before it was recorded: unknown)::

                 {"stage": "train" | "average" | "decide" | "narrow" | "export",
                  "parents": [{"sha256": <the parent file's SHA-256>, "path": <informative only>,
                               "role": <train only: "init_from" | "teacher_policy">}],
                  "recipe": None (the recipe's digest, once recipes exist)}

Every write is atomic and durable (a temporary file, fsynced, then ``os.replace``, then
the folder fsynced). A failed write (a full
disk) removes its temporary file and raises :class:`CheckpointWriteError`, one line;
the previous checkpoint is untouched. An interrupted one (a second Ctrl-C) removes it too.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypedDict

import torch
import torch.nn as nn

from agent_client import runlog
from agent_client.errors import InputFileError, OutputFileError
from agent_client.outputs import write_cause
from agent_client.rl.config import Config, config_dict, config_from
from agent_client.rl.network import QNetwork

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "CheckpointWriteError",
    "atomic_save",
    "read_checkpoint",
    "save_policy",
    "load_policy",
    "load_weights",
    "checkpoint_config",
    "digest",
    "with_decision",
    "average_policies",
    "narrow_policy",
    "export_policy",
    "POLICY_FIELDS",
    "Lineage",
    "Parent",
    "LINEAGE_STAGES",
    "file_sha256",
    "make_lineage",
    "upgrade",
]

CHECKPOINT_FORMAT = "vacc-ddqn"
CHECKPOINT_VERSION = 2
READABLE_VERSIONS = (1, 2)


class CheckpointWriteError(OutputFileError):
    """A checkpoint or replay file could not be written (e.g. the disk is full)."""


LINEAGE_STAGES = ("train", "average", "decide", "narrow", "export")
"""The steps that write a checkpoint's ``lineage["stage"]``."""


class _ParentFile(TypedDict):
    sha256: str
    path: str


class Parent(_ParentFile, total=False):
    """A file a checkpoint was made from: its SHA-256 identifies it, its path only hints."""

    role: str
    digest_of: str  # "weights": the SHA-256 is of its weights alone (vacc reproduce), else of the file


class Lineage(TypedDict):
    """What made a checkpoint (its ``lineage`` entry)."""

    stage: str
    parents: list[Parent]
    recipe: dict[str, Any] | None  # vacc reproduce's: recipe name, digest, stage name, seed, smoke


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes, as ``sha256sum`` prints it.

    Raises:
        InputFileError: the file cannot be read.
    """
    try:
        return runlog.file_sha256(path)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def make_lineage(stage: str, parents: Sequence[str | Path], roles: Sequence[str] | None = None) -> Lineage:
    """The lineage of a checkpoint that ``stage`` makes from the files ``parents``.

    Args:
        stage: one of :data:`LINEAGE_STAGES`.
        parents: the input checkpoints, hashed now (before anything can overwrite them).
        roles: what each parent was to the stage (training: ``init_from``, ``teacher_policy``).

    Raises:
        InputFileError: a parent cannot be read.
    """
    assert stage in LINEAGE_STAGES, stage
    listed: list[Parent] = []
    for i, path in enumerate(parents):
        parent: Parent = {"sha256": file_sha256(path), "path": str(path)}
        if roles is not None:
            parent["role"] = roles[i]
        listed.append(parent)
    return {"stage": stage, "parents": listed, "recipe": None}


def _feed(h: Any, obj: Any) -> None:
    """Hash ``obj`` canonically: dict keys sorted, tensors by dtype, shape and bytes."""
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    elif isinstance(obj, dict):
        h.update(f"D{len(obj)}".encode())
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"L{len(obj)}".encode())
        for x in obj:
            _feed(h, x)
    else:  # str, int, float, bool, None: repr is exact for each
        h.update(f"{type(obj).__name__}:{obj!r};".encode())


def digest(payload: dict[str, Any]) -> str:
    """SHA-256 (hex) of a checkpoint's contents, its own ``sha256`` entry left out."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in payload.items() if k != "sha256"})
    return h.hexdigest()


def atomic_save(obj: dict[str, Any], path: Path) -> None:
    """``torch.save`` ``obj`` (with its digest) to ``path`` through a temporary file.

    Raises:
        CheckpointWriteError: the write failed; the temporary file is removed and
            ``path`` keeps its previous contents.
    """
    obj = {**obj, "sha256": digest(obj)}
    write_atomically(path, lambda tmp: torch.save(obj, tmp))


def write_atomically(path: Path, write: Any) -> None:
    """Call ``write(tmp)``, then move ``tmp`` over ``path``; on failure remove ``tmp``.

    An interruption (a second Ctrl-C's SystemExit, a KeyboardInterrupt) also removes
    ``tmp`` and then propagates as it came.

    Raises:
        CheckpointWriteError: one line naming the file and the cause.
    """
    tmp = path.with_name(path.name + ".tmp")
    try:
        write(tmp)
        _fsync(tmp)  # the bytes on disk before the name points at them: a power loss leaves the old file
        os.replace(tmp, path)
        _fsync(path.parent)  # and the rename itself
    except (OSError, RuntimeError) as exc:  # torch.save wraps ENOSPC in a RuntimeError
        tmp.unlink(missing_ok=True)
        raise CheckpointWriteError(f"{path}: could not be written: {write_cause(exc)}; the previous file is kept") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load a checkpoint, check its envelope and its digest, and bring it to version 2.

    Raises:
        InputFileError: missing, truncated, corrupt (digest mismatch), not a
            checkpoint, or another version.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: checkpoint file not found")
    with open(path, "rb") as f:
        if f.read(4) != b"PK\x03\x04":  # torch.save writes a zip archive
            raise InputFileError(f"{path}: not a checkpoint (not a torch.save archive)")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch.load raises many types on corrupt bytes (even IndexError)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise InputFileError(f"{path}: not a readable checkpoint, truncated or corrupt ({type(exc).__name__}: {first[:200]})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(f"{path}: not a vacc DDQN checkpoint (no format tag {CHECKPOINT_FORMAT!r})")
    version = ckpt.get("version")
    if version not in READABLE_VERSIONS:
        raise InputFileError(f"{path}: checkpoint version {version!r}; this vacc reads versions {READABLE_VERSIONS}: use the vacc that wrote it")
    if version >= 2 and ckpt.get("sha256") != digest(ckpt):
        raise InputFileError(f"{path}: checkpoint is corrupt (its SHA-256 digest does not match its contents)")
    if not isinstance(ckpt.get("config"), dict) or not isinstance(ckpt.get("model"), dict):
        raise InputFileError(f"{path}: checkpoint lacks its config or model weights")
    if version == 1:  # the two trainers' old layouts
        ckpt["trainer"] = "streams" if ckpt.get("trainer") == "distributed" else "single"
        if isinstance(ckpt.get("replay"), str):
            ckpt["replay"] = [ckpt["replay"]]
    return ckpt


def checkpoint_config(ckpt: dict[str, Any], path: str | Path) -> Config:
    """The :class:`Config` a checkpoint was trained with.

    Raises:
        InputFileError: a setting out of range.
    """
    return config_from(ckpt["config"], path)


def load_weights(module: nn.Module, state: dict[str, Any], path: str | Path, what: str = "model") -> None:
    """``module.load_state_dict(state)``.

    Raises:
        InputFileError: the weights do not fit the network.
    """
    try:
        module.load_state_dict(state)
    except (RuntimeError, KeyError, TypeError) as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        detail = "; ".join(lines[1:4]) if len(lines) > 1 else (lines[0] if lines else "")
        raise InputFileError(f"{path}: {what} weights do not fit the network (wrong shape or layers): {detail[:300]}") from None


def save_policy(q: QNetwork, cfg: Config, path: str | Path, extra: dict[str, Any] | None = None,
                lineage: Lineage | None = None) -> None:
    """Write a policy-only checkpoint (weights + settings, < 5 MB), atomically.

    Args:
        lineage: what made it (see :func:`make_lineage`); None writes no ``lineage`` entry.

    Raises:
        CheckpointWriteError: see :func:`atomic_save`.
    """
    payload: dict[str, Any] = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "kind": "policy",
        "config": config_dict(cfg),
        "model": {k: v.detach().cpu() for k, v in q.state_dict().items()},
        "extra": extra or {},
    }
    if lineage is not None:
        payload["lineage"] = lineage
    atomic_save(payload, Path(path))


def load_policy(path: str | Path, device: str | torch.device = "cpu") -> tuple[QNetwork, Config]:
    """Load the Q-network (or, for a continuous action, the actor-critic) of a policy or
    training checkpoint, in eval mode.

    Raises:
        InputFileError: missing, truncated, corrupt, wrong format/version, or wrong shapes.
    """
    from agent_client.rl.actor_critic import network_of  # the actor-critic for a continuous action

    ckpt = read_checkpoint(path)
    cfg = checkpoint_config(ckpt, path)
    q = network_of(cfg)
    load_weights(q, ckpt["model"], path)
    return q.to(device).eval(), cfg  # type: ignore[return-value]


def upgrade(path: str | Path) -> bool:
    """Rewrite a version-1 checkpoint in this layout, with its digest; weights unchanged.

    Returns:
        Whether the file was rewritten (False: it already was version 2).

    Raises:
        InputFileError: not a readable checkpoint.
        CheckpointWriteError: the rewrite failed (the file is untouched).
    """
    ckpt = read_checkpoint(path)
    if ckpt["version"] == CHECKPOINT_VERSION:
        return False
    ckpt["config"] = config_dict(checkpoint_config(ckpt, path))  # records the serial schedule they used
    ckpt["version"] = CHECKPOINT_VERSION
    if ckpt.get("kind") == "policy":
        ckpt.pop("trainer", None)
        ckpt.pop("replay", None)
    atomic_save({k: v for k, v in ckpt.items() if k != "sha256"}, Path(path))
    return True


def with_decision(src: str | Path, dst: str | Path, decision: str, temperature: float | None = None,
                  brake_share: float | None = None, deadband: float | None = None, smoothing: float | None = None,
                  brake_confirm: int | None = None, full_brake_confirm: int | None = None) -> Config:
    """Write a copy of the policy ``src`` to the new file ``dst`` with another decision rule
    (``Config.decision``, and ``decision_temperature``, ``decision_brake_share``,
    ``decision_brake_confirm``, ``decision_full_brake_confirm``, ``decision_deadband`` and
    ``decision_smoothing`` if given);
    weights unchanged.

    Returns:
        The copy's config.

    Raises:
        InputFileError: ``src`` is not a readable checkpoint, the rule does not fit it, or
            ``dst`` exists (nothing saved is overwritten).
        CheckpointWriteError: the write failed.
    """
    ckpt = read_checkpoint(src)
    cfg = checkpoint_config(ckpt, src)
    if Path(dst).exists():
        raise InputFileError(f"{dst}: exists; give a new file for the copy")
    temperature = cfg.decision_temperature if temperature is None else temperature
    brake_share = cfg.decision_brake_share if brake_share is None else brake_share
    deadband = cfg.decision_deadband if deadband is None else deadband
    smoothing = cfg.decision_smoothing if smoothing is None else smoothing
    brake_confirm = cfg.decision_brake_confirm if brake_confirm is None else brake_confirm
    full_brake_confirm = cfg.decision_full_brake_confirm if full_brake_confirm is None else full_brake_confirm
    try:
        cfg = dataclasses.replace(cfg, decision=decision, decision_temperature=temperature, decision_brake_share=brake_share,
                                  decision_deadband=deadband, decision_smoothing=smoothing, decision_brake_confirm=brake_confirm,
                                  decision_full_brake_confirm=full_brake_confirm)
    except ValueError as exc:
        raise InputFileError(f"{src}: {exc}") from None
    ckpt["config"] = config_dict(cfg)
    ckpt["lineage"] = make_lineage("decide", [src])
    atomic_save({k: v for k, v in ckpt.items() if k != "sha256"}, Path(dst))
    return cfg


POLICY_FIELDS = ("scenario", "action", "zoom", "frame_stack", "stack_stride", "speed_scale", "decision",
                 "decision_temperature", "decision_brake_share", "decision_deadband",
                 "decision_smoothing", "decision_brake_confirm", "decision_full_brake_confirm")
"""The settings that decide what a policy sees and how it acts: averaged policies must agree on them.
(The set speed and the pre-roll only shape training episodes; a drive takes both from its own options.)"""


def _source(path: str | Path, ckpt: dict[str, Any], share: float) -> dict[str, Any]:
    """What an average records of one of its sources (``share``: its weight over the sum)."""
    return {"path": str(path), "step": int(ckpt.get("extra", {}).get("step", 0)), "sha256": ckpt.get("sha256"),
            "share": share}


def _soup_weights(srcs: list[str | Path], weights: list[float] | None, dst: str | Path) -> list[float]:
    """The sources' weights in the average, checked (1 each when ``weights`` is None)."""
    if weights is None:
        return [1.0] * len(srcs)
    if len(weights) != len(srcs):
        raise InputFileError(f"{dst}: {len(weights)} weights for {len(srcs)} policies; give one weight per policy")
    if not all(math.isfinite(w) and w > 0 for w in weights):
        raise InputFileError(f"{dst}: weights must be finite and positive numbers, got {weights}")
    return [float(w) for w in weights]


def average_policies(srcs: list[str | Path], dst: str | Path, weights: list[float] | None = None) -> Config:
    """Write the element-wise mean of the weights of the policies ``srcs`` to the new file ``dst``
    (a "model soup", Wortsman et al. 2022: fine-tunes of one network from the same start average
    into one network whose failures are not the union of theirs). ``weights`` (positive, one per
    source, normalised to sum to 1) weight the mean; equal shares by default. Settings are the
    first's; the copy records each source's path, step, digest and share (``extra["average_of"]``).

    Returns:
        The average's config.

    Raises:
        InputFileError: fewer than two sources, one given twice, one unreadable, one that differs
            from the first in a :data:`POLICY_FIELDS` setting, in its layers or in a non-float
            tensor, weights that are not one positive number per source, or ``dst`` exists.
        CheckpointWriteError: the write failed.
    """
    if len(srcs) < 2:
        raise InputFileError(f"{dst}: give at least two policies to average ({len(srcs)} given)")
    if Path(dst).exists():
        raise InputFileError(f"{dst}: exists; give a new file for the average")
    raw = _soup_weights(srcs, weights, dst)
    weight_sum = math.fsum(raw)
    shares = [w / weight_sum for w in raw]
    first = read_checkpoint(srcs[0])
    cfg = checkpoint_config(first, srcs[0])
    floats = {k for k, v in first["model"].items() if v.is_floating_point()}
    # the weighted sum over the sum of the weights: equal weights give sum / n exactly
    total = {k: raw[0] * v.detach().to(torch.float64) for k, v in first["model"].items() if k in floats}
    sources = [_source(srcs[0], first, shares[0])]
    for src, w, share in zip(srcs[1:], raw[1:], shares[1:], strict=True):
        ckpt = read_checkpoint(src)
        if ckpt.get("sha256") is not None and ckpt.get("sha256") in {x["sha256"] for x in sources}:
            raise InputFileError(f"{src}: the same policy is given twice; each source counts once")
        other = checkpoint_config(ckpt, src)
        for name in POLICY_FIELDS:
            if getattr(other, name) != getattr(cfg, name):
                raise InputFileError(f"{src}: {name} is {getattr(other, name)!r}, {srcs[0]}'s is {getattr(cfg, name)!r}; only policies that see and act alike average")
        model = ckpt["model"]
        if {k: tuple(v.shape) for k, v in model.items()} != {k: tuple(v.shape) for k, v in first["model"].items()}:
            raise InputFileError(f"{src}: its layers differ from {srcs[0]}'s; only one network's weights average")
        for k, v in model.items():
            if k in floats:
                total[k] += w * v.to(torch.float64)
            elif not torch.equal(v, first["model"][k]):  # counters and the like have no mean
                raise InputFileError(f"{src}: its {k} differs from {srcs[0]}'s and is not a float tensor to average")
        sources.append(_source(src, ckpt, share))
    state = {k: (total[k] / weight_sum).to(v.dtype) if k in floats else v for k, v in first["model"].items()}
    q = QNetwork.of(cfg)
    load_weights(q, state, srcs[0])
    save_policy(q, cfg, dst, {"step": sources[0]["step"], "average_of": sources}, make_lineage("average", srcs))
    return cfg


def _keep(importance: torch.Tensor, n: int) -> torch.Tensor:
    """The indices of the ``n`` largest importances, in their original order."""
    return importance.topk(n).indices.sort().values


def narrow_policy(src: str | Path, dst: str | Path, conv_channels: tuple[int, int, int], hidden: int) -> Config:
    """Write ``src``'s network cut down to ``conv_channels`` and ``hidden`` units as the new
    policy ``dst``: the start of a distillation into a faster network (``vacc train --teacher
    policy --init-from DST``) that keeps the teacher's strongest features instead of none.

    Each layer keeps the units whose weights in and out have the largest product of L2
    norms (magnitude pruning of whole channels, Li et al. 2017), in their order; the layers
    after it read only those. Cut so, the network computes something else: it must be trained.

    Returns:
        The new policy's config (``src``'s, with the new widths).

    Raises:
        InputFileError: ``src`` unreadable, a width larger than ``src``'s or below 1, or
            ``dst`` exists.
        CheckpointWriteError: the write failed.
    """
    if Path(dst).exists():
        raise InputFileError(f"{dst}: exists; give a new file for the narrowed policy")
    q, cfg = load_policy(src)
    if getattr(q, "recurrent", False):
        raise InputFileError(f"{src}: a recurrent policy (--recurrent {cfg.recurrent}) cannot be narrowed: its GRU's widths are not cut down")
    old = (*(c.out_channels for c in q._convs), q._linears[0].out_features)
    new = (*conv_channels, hidden)
    if len(new) != 4 or not all(1 <= n <= o for n, o in zip(new, old, strict=True)):
        raise InputFileError(f"{src}: its widths are {old[:3]}, {old[3]}; narrowing needs each new width from 1 to that, got {tuple(new[:-1])}, {hidden}")
    sd = {k: v.detach() for k, v in q.state_dict().items()}
    convs = [f"conv.{i}" for i in (0, 2, 4)]
    fc1, fc2 = "fc.0", "fc.2"
    heads = [h for h in ("gap_head", "closing_head") if f"{h}.weight" in sd]
    n_conv = sd[f"{fc1}.weight"].shape[1] - cfg.frame_stack * (1 + q.n_controls)  # flattened conv features
    spatial = n_conv // old[2]  # fc1 columns per conv3 channel (channel-major, as flatten lays them)
    fc1_by_channel = sd[f"{fc1}.weight"][:, :n_conv].reshape(old[3], old[2], spatial)
    outgoing = [sd[f"{convs[1]}.weight"], sd[f"{convs[2]}.weight"], fc1_by_channel]
    keeps = []
    for i, name in enumerate(convs):
        w_in = sd[f"{name}.weight"].flatten(1).norm(dim=1)
        w_out = outgoing[i].transpose(0, 1).flatten(1).norm(dim=1)
        keeps.append(_keep(w_in * w_out, conv_channels[i]))
    out_w = torch.cat([sd[f"{fc2}.weight"], *(sd[f"{h}.weight"] for h in heads)])
    keep_h = _keep(sd[f"{fc1}.weight"].norm(dim=1) * out_w.norm(dim=0), hidden)
    state = dict(sd)
    prev: torch.Tensor | None = None
    for name, keep in zip(convs, keeps, strict=True):
        w = sd[f"{name}.weight"][keep]
        state[f"{name}.weight"] = w if prev is None else w[:, prev]
        state[f"{name}.bias"] = sd[f"{name}.bias"][keep]
        prev = keep
    conv_cols = (keeps[2][:, None] * spatial + torch.arange(spatial)).flatten()  # the kept channels' columns
    cols = torch.cat([conv_cols, torch.arange(n_conv, sd[f"{fc1}.weight"].shape[1])])  # and the speeds, controls
    state[f"{fc1}.weight"] = sd[f"{fc1}.weight"][keep_h][:, cols]
    state[f"{fc1}.bias"] = sd[f"{fc1}.bias"][keep_h]
    for name in (fc2, *heads):
        state[f"{name}.weight"] = sd[f"{name}.weight"][:, keep_h]
    narrow_cfg = dataclasses.replace(cfg, conv_channels=tuple(conv_channels), hidden=hidden)
    narrow = QNetwork.of(narrow_cfg)
    load_weights(narrow, {k: v.clone() for k, v in state.items()}, src)
    save_policy(narrow, narrow_cfg, dst, {"narrowed_from": str(src), "widths_from": list(old)}, make_lineage("narrow", [src]))
    return narrow_cfg


def export_policy(src: str | Path, dst: str | Path) -> int:
    """Write the weights and settings of the checkpoint ``src`` (a training run's ``latest.pt``,
    or a policy) as a policy-only file ``dst``, as the trainer writes ``best.pt``.

    Returns:
        The step ``src`` was taken at (0 when it does not say).

    Raises:
        InputFileError: ``src`` is not a readable checkpoint, or ``dst`` exists.
        CheckpointWriteError: the write failed.
    """
    if Path(dst).exists():
        raise InputFileError(f"{dst}: exists; give a new file for the policy")
    ckpt = read_checkpoint(src)
    step = int(ckpt.get("state", {}).get("global_step", ckpt.get("extra", {}).get("step", 0)))
    q, cfg = load_policy(src)
    extra = {"step": step, "from": str(src)}
    if "average_of" in ckpt.get("extra", {}):  # a mean (a recipe's swa output) stays known as one
        extra["average_of"] = ckpt["extra"]["average_of"]
    save_policy(q, cfg, dst, extra, make_lineage("export", [src]))
    return step
