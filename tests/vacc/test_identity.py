"""`vacc reproduce`'s bit-for-bit check: stages with known weights, compared by the SHA-256 of
their weights, and the model against the shipped file by its policy's (weights and decision
rule), at the recipe's own seed only."""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

import torch

from agent_client.rl.checkpoint import (
    atomic_save,
    checkpoint_config,
    read_checkpoint,
    with_decision,
)
from vacc.recipes import RECIPES_DIR, parse_recipe
from vacc.reproduce import identity, identity_line, policy_sha256, weights_sha256

MODELS = Path(__file__).resolve().parents[2] / "models"


def _recipe(known: str | None):
    content = tomllib.loads((RECIPES_DIR / "ev-force.toml").read_text())
    for stage in content["stage"]:
        stage.pop("known_weights", None)  # only the first stage's, as given
    if known:
        content["stage"][0]["known_weights"] = known
    return parse_recipe(content, Path("recipes/ev-force.toml"))


def _perturbed(src: Path, dst: Path) -> Path:
    ckpt = torch.load(src, weights_only=True)
    name = next(k for k, v in ckpt["model"].items() if v.is_floating_point())
    ckpt["model"][name] = ckpt["model"][name].clone()
    ckpt["model"][name].view(-1)[0] += 1e-6  # one weight, one part in a million
    atomic_save(ckpt, dst)  # with its own digest: a valid checkpoint, other weights
    return dst


def test_identical_and_differing_weights_are_told_apart(tmp_path, monkeypatch):
    shipped_dir = tmp_path / "models"
    shipped_dir.mkdir()
    shutil.copyfile(MODELS / "ev-force.pt", shipped_dir / "ev-force.pt")
    monkeypatch.setenv("VACC_MODELS", str(shipped_dir))
    same = weights_sha256(MODELS / "ev-force.pt")
    other = weights_sha256(_perturbed(MODELS / "ev-force.pt", tmp_path / "other.pt"))
    assert same != other
    recipe = _recipe(known=same)
    first = recipe.stages[0].name
    opts = {"seed": recipe.seed, "smoke": False}

    ident = identity(recipe, {first: {"weights_sha256": same}}, MODELS / "ev-force.pt", opts)
    assert ident["compared"] and [c["identical"] for c in ident["checks"]] == [True, True]
    assert "DIFFERS" not in identity_line(ident)

    ident = identity(recipe, {first: {"weights_sha256": other}}, tmp_path / "other.pt", opts)
    assert [c["identical"] for c in ident["checks"]] == [False, False]
    assert identity_line(ident) == f"bit for bit: stage {first} DIFFERS, other.pt against {shipped_dir / 'ev-force.pt'} DIFFERS"


def test_the_same_weights_under_another_decision_rule_are_another_model(tmp_path, monkeypatch):
    shipped_dir = tmp_path / "models"
    shipped_dir.mkdir()
    shutil.copyfile(MODELS / "ev-eco.pt", shipped_dir / "ev-eco.pt")
    monkeypatch.setenv("VACC_MODELS", str(shipped_dir))
    ruled = tmp_path / "ev-eco.pt"
    shipped = checkpoint_config(read_checkpoint(MODELS / "ev-eco.pt"), MODELS / "ev-eco.pt")
    with_decision(MODELS / "ev-eco.pt", ruled, "mean", temperature=shipped.decision_temperature + 1.0)
    assert weights_sha256(ruled) == weights_sha256(MODELS / "ev-eco.pt")
    assert policy_sha256(ruled) != policy_sha256(MODELS / "ev-eco.pt")
    content = tomllib.loads((RECIPES_DIR / "ev-eco.toml").read_text())
    recipe = parse_recipe(content, Path("recipes/ev-eco.toml"))
    opts = {"seed": recipe.seed, "smoke": False}
    done = {s.name: {"weights_sha256": weights_sha256(MODELS / "ev-eco.pt")} for s in recipe.stages}
    ident = identity(recipe, done, ruled, opts)
    assert [c["identical"] for c in ident["checks"]] == [True, False]  # the stage's weights, then the policy
    assert identity(recipe, done, shipped_dir / "ev-eco.pt", opts)["checks"][-1]["identical"]


def test_a_replicate_or_a_smoke_run_is_not_compared(tmp_path, monkeypatch):
    monkeypatch.setenv("VACC_MODELS", str(tmp_path))
    recipe = _recipe(known="ab" * 32)
    for opts, why in (({"seed": recipe.seed + 1, "smoke": False}, "is a replicate"), ({"seed": recipe.seed, "smoke": True}, "--smoke")):
        ident = identity(recipe, {}, MODELS / "ev-force.pt", opts)
        assert not ident["compared"] and why in identity_line(ident)


def test_nothing_known_is_said(tmp_path, monkeypatch):
    monkeypatch.setenv("VACC_MODELS", str(tmp_path))  # no shipped file there
    recipe = _recipe(known=None)
    ident = identity(recipe, {}, MODELS / "ev-force.pt", {"seed": recipe.seed, "smoke": False})
    assert ident["compared"] and not ident["checks"]
    assert identity_line(ident) == "bit for bit: nothing known to compare with"
