"""Recipes: one TOML file per shipped model, ``recipes/<model>.toml``, that rebuilds it.

A recipe is an ordered list of stages, each with every option written out, and the
checks (gates) its model must pass. Its layout::

    [recipe]                 name, scenario ("ice" | "ev"), description, seed (the replicate its
                             stages' seeds are written for), and optional: cpu_path ("avx2", the
                             default; vacc.host.CPU_PATHS) and reseed_from (the stage where
                             `--seed N` replicates begin; default the first)
    [ablation]               note: which stages are candidates to drop (optional)
    [[stage]]                name, kind, note, known_weights and cpu_path (optional), then the kind's keys:
      train                  every Config field by name (``vacc train``'s options, snake_case;
                             None written "none"), and output = "best" | "latest" | "eval:STEP" |
                             "swa:STEP" (the even mean of the evaluations kept from STEP on:
                             stochastic weight averaging over the run's tail)
      average                inputs = ["stage:a", "stage:b"], weights = [1.0, 1.0]
      decide                 input, decision, temperature, brake_share, brake_confirm,
                             full_brake_confirm, deadband, smoothing
      narrow                 input, conv_channels = [c1, c2, c3], hidden
      export                 input
      shipped                model (a shipped model's name: models/<model>.pt, which its own
                             recipe rebuilds), weights_sha256 (its weights, checked)
    [gates.tests]            seed, max_gap_rmse_m (each of test-1..test-4), no collision
    [gates.safety]           seeds, scenarios (lead scenarios; each run must pass)
    [gates.random]           seeds, max_gap_rmse_m (the worst seed), no collision
    [gates.energy]           max_ratio_to_acc (the mean over the tests; eco models)
    [gates.comfort]          max_jerk_rms_mps3, max_iso_jerk_share (the mean over the tests)
                             (each gate may carry a note)

A stage's inputs (``init_from``, ``teacher_policy``, ``input``, ``inputs``) name an
earlier stage as ``"stage:<name>"``, never a path: nothing outside the recipe and the
repository is needed. The recipe's digest is the SHA-256 of its canonical content
(:func:`digest`), recorded in every checkpoint a stage writes.

A stage's ``known_weights`` is the SHA-256 of the weights that stage made for the shipped model,
when it was first built or in the rebuild that was shipped (:func:`vacc.reproduce.weights_sha256`
of a file kept in git history or of that rebuild's stage): a rebuild
with the recipe's own seed says whether it made them again bit for bit. It records an
outcome, not an input, so it is left out of the digest: writing one in does not invalidate
a run under way. ``cpu_path`` says how the stages run, not what they are, so it is left out too.

This module parses, checks and digests; :mod:`vacc.reproduce` runs a recipe and
:mod:`vacc.gates` checks its model.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from pathlib import Path
from typing import Any, NamedTuple

from agent_client.rl.config import DECISIONS, Config, ConfigError, config_dict
from protocol.scenarios import LEAD_SCENARIOS, SCENARIOS
from vacc.host import CPU_PATHS
from vacc.runs import parse_seeds

__all__ = [
    "RecipeError", "Stage", "Recipe", "STAGE_KINDS", "STAGE_REF", "NONE", "RECIPES_DIR", "GATE_KEYS",
    "load_recipe", "parse_recipe", "recipe_path", "digest", "stage_config", "stage_refs", "keyed_options", "LATE_OPTIONS",
]  # fmt: skip

RECIPES_DIR = Path(__file__).resolve().parent.parent / "recipes"
STAGE_REF = "stage:"
DEFAULT_CPU_PATH = "avx2"
"""A recipe's kernels where it names none: the path every x86-64 CPU since 2013 runs, so that
rebuilds on different machines agree bit for bit (:data:`vacc.host.CPU_PATHS`)."""
NONE = "none"
"""How a recipe writes an unset (None) train option: TOML has no null."""

STAGE_KINDS: dict[str, tuple[str, ...]] = {
    "train": ("output",),  # and every Config field
    "average": ("inputs", "weights"),
    "decide": ("input", "decision", "temperature", "brake_share", "brake_confirm", "full_brake_confirm", "deadband", "smoothing"),
    "narrow": ("input", "conv_channels", "hidden"),
    "export": ("input",),
    "shipped": ("model", "weights_sha256"),
}
"""Each stage kind's keys besides name, kind and note (all required)."""

TRAIN_REFS = ("init_from", "teacher_policy")  # the Config fields that name a checkpoint
OPTIONAL_KEYS = ("note", "known_weights", "cpu_path")
COMMON_KEYS = ("name", "kind", *OPTIONAL_KEYS)
OUTCOME_KEYS = ("known_weights",)  # what a stage is known to make: not part of the digest
RECIPE_KEYS = ("name", "scenario", "description", "seed", "cpu_path", "reseed_from")
HOW_KEYS = ("cpu_path",)  # how the stages run, not what they are: not part of the digest
LATE_OPTIONS: dict[str, Any] = {"critic_warmup": 0, "actor_levels": "none", "bc_weight": 0.0, "trunk_training": "critic", "emergency": "closing"}
"""Train options added after recipes were first digested, at the value that changes nothing:
left out of a recipe's digest and a stage's key (:func:`keyed_options`), so that writing them
into every recipe leaves every run folder and ``--reuse`` valid."""
GATE_KEYS: dict[str, tuple[str, ...]] = {
    "tests": ("seed", "max_gap_rmse_m"),
    "safety": ("seeds", "scenarios"),
    "random": ("seeds", "max_gap_rmse_m"),
    "energy": ("max_ratio_to_acc",),
    "comfort": ("max_jerk_rms_mps3", "max_iso_jerk_share"),
}
"""Each gate's keys (all required where the gate is given)."""


class RecipeError(ValueError):
    """A recipe that cannot be read or is not valid: one line naming the file and the key."""


class Stage(NamedTuple):
    """One stage of a recipe: its name, kind and options (as written, refs unresolved)."""

    name: str
    kind: str
    options: dict[str, Any]
    note: str
    known_weights: str | None = None
    cpu_path: str | None = None  # its kernels where they are not the recipe's (the machine it was first made on)


class Recipe(NamedTuple):
    """A checked recipe."""

    path: Path
    name: str
    scenario: str
    description: str
    seed: int
    stages: tuple[Stage, ...]
    gates: dict[str, dict[str, Any]]
    digest: str
    cpu_path: str = DEFAULT_CPU_PATH  # vacc.host.CPU_PATHS: the kernels its train stages run on
    reseed_from: str | None = None  # the first stage that --seed N replicates (None: every stage)

    def stage(self, name: str) -> Stage:
        """The stage called ``name``.

        Raises:
            KeyError: there is none.
        """
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(name)


def recipe_path(model_or_file: str | Path) -> Path:
    """A recipe file: the path itself if it is a file, else ``recipes/<name>.toml``.

    Raises:
        RecipeError: neither exists.
    """
    path = Path(model_or_file)
    if path.suffix == ".toml" or path.is_file():
        if not path.is_file():
            raise RecipeError(f"{path}: no such recipe file")
        return path
    found = RECIPES_DIR / f"{model_or_file}.toml"
    if not found.is_file():
        known = ", ".join(sorted(p.stem for p in RECIPES_DIR.glob("*.toml")))
        raise RecipeError(f"{model_or_file!r} is neither a recipe file nor a recipe in {RECIPES_DIR} ({known})")
    return found


def digest(content: dict[str, Any]) -> str:
    """SHA-256 (hex) of a recipe's canonical content: its parsed TOML as JSON, keys sorted,
    no whitespace. Comments and layout do not count; every value does (notes too).
    :func:`parse_recipe` passes it the content without the stages' ``known_weights``."""
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def load_recipe(model_or_file: str | Path) -> Recipe:
    """Read and check a recipe (see :func:`recipe_path` for the name).

    Raises:
        RecipeError: one line naming the file and the key at fault.
    """
    path = recipe_path(model_or_file)
    try:
        content = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise RecipeError(f"{path}: cannot be read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise RecipeError(f"{path}: not valid TOML ({exc})") from None
    return parse_recipe(content, path)


def _bad(path: Path, where: str, message: str) -> RecipeError:
    return RecipeError(f"{path}: {where}: {message}")


def _unknown(path: Path, where: str, table: dict[str, Any], allowed: tuple[str, ...], optional: tuple[str, ...] = OPTIONAL_KEYS + HOW_KEYS) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _bad(path, f"{where}.{extra[0]}", f"unknown key; expected {', '.join(allowed)}")
    missing = [k for k in allowed if k not in table and k not in optional]
    if missing:
        raise _bad(path, f"{where}.{missing[0]}", "missing (every option is written out)")


def parse_recipe(content: dict[str, Any], path: Path) -> Recipe:
    """Check a parsed recipe and return it.

    Raises:
        RecipeError: one line naming ``path`` and the key at fault: an unknown or missing
            key, a bad value, a stage reference to no stage or to a later one (a cycle),
            a path where a stage reference is required.
    """
    _unknown(path, "top level", content, ("recipe", "ablation", "stage", "gates"))
    head = content.get("recipe")
    if not isinstance(head, dict):
        raise _bad(path, "[recipe]", "missing table")
    _unknown(path, "recipe", head, RECIPE_KEYS, optional=("cpu_path", "reseed_from"))
    if head["scenario"] not in SCENARIOS:
        raise _bad(path, "recipe.scenario", f"{head['scenario']!r} is not one of {', '.join(SCENARIOS)}")
    if not isinstance(head["seed"], int) or head["seed"] < 0:
        raise _bad(path, "recipe.seed", f"{head['seed']!r} is not a whole number >= 0")
    if not isinstance(head["name"], str) or not head["name"]:
        raise _bad(path, "recipe.name", "must be a non-empty string")
    cpu_path = head.get("cpu_path", DEFAULT_CPU_PATH)
    if cpu_path not in CPU_PATHS:
        raise _bad(path, "recipe.cpu_path", f"{cpu_path!r} is not one of {', '.join(CPU_PATHS)}")
    if "ablation" in content and not isinstance(content["ablation"], dict):
        raise _bad(path, "ablation", "must be a table")
    raw_stages = content.get("stage")
    if not isinstance(raw_stages, list) or not raw_stages:
        raise _bad(path, "[[stage]]", "a recipe needs at least one stage")
    stages: list[Stage] = []
    for i, raw in enumerate(raw_stages):
        stages.append(_parse_stage(path, i, raw, [s.name for s in stages]))
    reseed_from = head.get("reseed_from")
    if reseed_from is not None and reseed_from not in [s.name for s in stages]:
        raise _bad(path, "recipe.reseed_from", f"{reseed_from!r} is no stage of this recipe")
    gates = _parse_gates(path, content.get("gates", {}))
    inputs = {**content, "recipe": {k: v for k, v in head.items() if k not in HOW_KEYS},
              "stage": [keyed_options({k: v for k, v in raw.items() if k not in OUTCOME_KEYS + HOW_KEYS}) for raw in raw_stages]}  # fmt: skip
    return Recipe(path, head["name"], head["scenario"], head["description"], head["seed"], tuple(stages), gates, digest(inputs), cpu_path, reseed_from)


def _parse_stage(path: Path, i: int, raw: Any, earlier: list[str]) -> Stage:
    """One ``[[stage]]`` entry, checked against the stages before it."""
    if not isinstance(raw, dict):
        raise _bad(path, f"stage[{i}]", "must be a table")
    name, kind = raw.get("name"), raw.get("kind")
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "-_" for c in name):
        raise _bad(path, f"stage[{i}].name", f"{name!r} is not a name of letters, digits, - and _")
    where = f"stage {name!r}"
    if name in earlier:
        raise _bad(path, f"{where}.name", "another stage has this name")
    if kind not in STAGE_KINDS:
        raise _bad(path, f"{where}.kind", f"{kind!r} is not one of {', '.join(STAGE_KINDS)}")
    allowed = COMMON_KEYS + STAGE_KINDS[kind] + (tuple(f.name for f in dataclasses.fields(Config)) if kind == "train" else ())
    _unknown(path, where, raw, allowed)
    options = {k: v for k, v in raw.items() if k not in COMMON_KEYS}
    for key in stage_ref_keys(kind):
        values = options[key] if isinstance(options[key], list) else [options[key]]
        for v in values:
            _check_ref(path, f"{where}.{key}", v, name, earlier, optional=key in TRAIN_REFS)
    known = raw.get("known_weights")
    if known is not None and not _is_sha256(known):
        raise _bad(path, f"{where}.known_weights", f"{known!r} is not a SHA-256 (64 lowercase hex digits)")
    cpu_path = raw.get("cpu_path")
    if cpu_path is not None and (kind != "train" or cpu_path not in CPU_PATHS):
        raise _bad(path, f"{where}.cpu_path", f"{cpu_path!r}: a train stage's kernels, one of {', '.join(CPU_PATHS)}")
    stage = Stage(name, kind, options, str(raw.get("note", "")), known, cpu_path)
    if kind == "train":
        _check_train(path, where, stage)
    else:
        _check_surgery(path, where, stage)
    return stage


def _is_sha256(value: Any) -> bool:
    return isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdef" for c in value)


def keyed_options(options: dict[str, Any]) -> dict[str, Any]:
    """``options`` without the :data:`LATE_OPTIONS` at their inert values: what a digest or a key hashes."""
    return {k: v for k, v in options.items() if not (k in LATE_OPTIONS and v == LATE_OPTIONS[k])}


def stage_ref_keys(kind: str) -> tuple[str, ...]:
    """The keys of a stage of ``kind`` that name other stages."""
    return {"train": TRAIN_REFS, "average": ("inputs",), "shipped": ()}.get(kind, ("input",))


def stage_refs(stage: Stage) -> list[str]:
    """The names of the stages ``stage`` reads, in the order its options give them."""
    names = []
    for key in stage_ref_keys(stage.kind):
        value = stage.options[key]
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str) and v.startswith(STAGE_REF):
                names.append(v.removeprefix(STAGE_REF))
    return names


def _check_ref(path: Path, where: str, value: Any, own: str, earlier: list[str], optional: bool) -> None:
    if optional and value == NONE:  # init_from and teacher_policy: unset
        return
    if not isinstance(value, str) or not value.startswith(STAGE_REF):
        hint = " (a path: name the stage that makes it instead)" if isinstance(value, str) and ("/" in value or value.endswith(".pt")) else ""
        raise _bad(path, where, f"{value!r} is not a stage reference \"{STAGE_REF}<name>\"{hint}")
    target = value.removeprefix(STAGE_REF)
    if target == own:
        raise _bad(path, where, f"{value!r} names its own stage (a cycle)")
    if target not in earlier:
        raise _bad(path, where, f"{value!r} names no earlier stage (stages run in order; a later one would make a cycle)")


def stage_config(stage: Stage, inputs: dict[str, str] | None = None) -> Config:
    """The :class:`Config` of a train stage; ``inputs`` maps its stage references to files
    (unresolved references stay as written, for checking).

    Raises:
        ConfigError: a setting out of range (``field`` names it).
        ValueError, TypeError: a value of the wrong kind.
    """
    kw: dict[str, Any] = {}
    defaults = config_dict(Config())
    for f in dataclasses.fields(Config):
        v = stage.options[f.name]
        if v == NONE and str(f.type).endswith("| None"):  # teacher = "none" is a value, not unset
            v = None
        elif f.name in TRAIN_REFS and inputs is not None:
            v = inputs[v.removeprefix(STAGE_REF)]
        elif isinstance(defaults[f.name], (list, tuple)):
            if not isinstance(v, list):
                raise TypeError(f"{f.name}: want a list, got {v!r}")
            v = tuple(v)
        elif isinstance(defaults[f.name], float) and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        kw[f.name] = v
    for f in dataclasses.fields(Config):
        want = type(defaults[f.name]) if defaults[f.name] is not None else None
        v = kw[f.name]
        if want in (int, bool, str) and v is not None and type(v) is not want:
            raise TypeError(f"{f.name}: want {want.__name__}, got {v!r}")
    return Config(**kw)


def _check_train(path: Path, where: str, stage: Stage) -> None:
    # a stage may train for the other scenario (ev-gap starts from an ICE policy); the gates drive the recipe's
    try:
        cfg = stage_config(stage)
    except ConfigError as exc:
        raise _bad(path, f"{where}.{exc.field}", str(exc)) from None
    except (TypeError, ValueError) as exc:
        raise _bad(path, where, str(exc)) from None
    out = stage.options["output"]
    form, _, step = out.partition(":") if isinstance(out, str) else ("", "", "")
    if out not in ("best", "latest") and not (form in ("eval", "swa") and step.isdigit()):
        raise _bad(path, f"{where}.output", f"{out!r} is not best, latest, eval:STEP or swa:STEP")
    if step.isdigit() and not cfg.keep_evals:
        raise _bad(path, f"{where}.output", f"{out!r} needs keep_evals = true (each evaluation's policy is kept as evals/STEP.pt)")
    if form == "swa" and not (0 < cfg.eval_every and int(step) < cfg.total_steps):
        raise _bad(path, f"{where}.output", f"{out!r} needs eval_every > 0 and STEP below total_steps ({cfg.total_steps}): it averages the evaluations kept from STEP on")


def _check_surgery(path: Path, where: str, stage: Stage) -> None:
    o = stage.options
    if stage.kind == "average":
        if not isinstance(o["inputs"], list) or len(o["inputs"]) < 2:
            raise _bad(path, f"{where}.inputs", "an average needs two or more stages")
        if len(set(o["inputs"])) != len(o["inputs"]):
            raise _bad(path, f"{where}.inputs", "a stage is given twice; each source counts once")
        w = o["weights"]
        if not isinstance(w, list) or len(w) != len(o["inputs"]) or not all(isinstance(x, (int, float)) and x > 0 for x in w):
            raise _bad(path, f"{where}.weights", f"want one positive number per input, got {w!r}")
    elif stage.kind == "decide":
        if o["decision"] not in DECISIONS:
            raise _bad(path, f"{where}.decision", f"{o['decision']!r} is not one of {', '.join(DECISIONS)}")
        for key in ("temperature", "brake_share", "deadband", "smoothing"):
            if not isinstance(o[key], (int, float)) or isinstance(o[key], bool):
                raise _bad(path, f"{where}.{key}", f"{o[key]!r} is not a number")
        for key in ("brake_confirm", "full_brake_confirm"):
            if not isinstance(o[key], int) or isinstance(o[key], bool) or o[key] < 1:
                raise _bad(path, f"{where}.{key}", f"{o[key]!r} is not a whole number >= 1")
    elif stage.kind == "shipped":
        if not isinstance(o["model"], str) or not o["model"] or not all(c.isalnum() or c in "-_" for c in o["model"]):
            raise _bad(path, f"{where}.model", f"{o['model']!r} is not a shipped model's name (models/<name>.pt)")
        if not _is_sha256(o["weights_sha256"]):
            raise _bad(path, f"{where}.weights_sha256", f"{o['weights_sha256']!r} is not a SHA-256 (64 lowercase hex digits)")
    elif stage.kind == "narrow":
        c = o["conv_channels"]
        if not isinstance(c, list) or len(c) != 3 or not all(isinstance(x, int) and x >= 1 for x in c):
            raise _bad(path, f"{where}.conv_channels", f"want three whole numbers >= 1, got {c!r}")
        if not isinstance(o["hidden"], int) or o["hidden"] < 1:
            raise _bad(path, f"{where}.hidden", f"{o['hidden']!r} is not a whole number >= 1")


def _parse_gates(path: Path, gates: Any) -> dict[str, dict[str, Any]]:
    if not isinstance(gates, dict):
        raise _bad(path, "gates", "must be a table")
    _unknown_only(path, "gates", gates, tuple(GATE_KEYS))
    for name, table in gates.items():
        if not isinstance(table, dict):
            raise _bad(path, f"gates.{name}", "must be a table")
        _unknown(path, f"gates.{name}", table, GATE_KEYS[name] + ("note",))
        for key, value in table.items():
            if key == "note":
                continue
            if key == "seeds":
                try:
                    parse_seeds(value)
                except (ValueError, AttributeError):
                    raise _bad(path, f"gates.{name}.seeds", f"{value!r} is not a seed list like 0-9") from None
            elif key == "scenarios":
                unknown = [s for s in value if s not in LEAD_SCENARIOS] if isinstance(value, list) else [value]
                if unknown or not value:
                    raise _bad(path, f"gates.{name}.scenarios", f"{unknown[0] if unknown else value!r} is not a lead scenario ({', '.join(LEAD_SCENARIOS)})")
            elif key == "seed":
                if not isinstance(value, int) or value < 0:
                    raise _bad(path, f"gates.{name}.seed", f"{value!r} is not a whole number >= 0")
            elif not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise _bad(path, f"gates.{name}.{key}", f"{value!r} is not a number >= 0")
    return gates


def _unknown_only(path: Path, where: str, table: dict[str, Any], allowed: tuple[str, ...]) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _bad(path, f"{where}.{extra[0]}", f"unknown key; expected some of {', '.join(allowed)}")
