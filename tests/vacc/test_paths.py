"""Where --models points by default: $VACC_MODELS, ./models, the checkout's models/."""

from __future__ import annotations

from pathlib import Path

import pytest

from vacc import paths
from vacc.demo import demo
from vacc.evaluate import evaluate

CHECKOUT = Path(__file__).resolve().parents[2]


def _default_models(command) -> str:
    """The --models a command would run with, from click's own default handling."""
    with command.make_context(command.name, ["--out", "unused"] if command is evaluate else []) as ctx:
        return ctx.params["models"]


@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    """A current folder outside the checkout, with no $VACC_MODELS."""
    monkeypatch.delenv(paths.MODELS_ENV, raising=False)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_outside_a_checkout_the_shipped_models_are_found(elsewhere):
    assert paths.checkout_models() == CHECKOUT / "models"
    assert (paths.models_dir() / "ice-gap.pt").is_file()
    for command in (evaluate, demo):
        assert Path(_default_models(command)) == CHECKOUT / "models"


def test_a_models_folder_here_comes_before_the_checkouts(elsewhere):
    (elsewhere / "models").mkdir()
    assert paths.models_dir() == Path("models")
    assert _default_models(evaluate) == "models"


def test_the_environment_variable_comes_first(elsewhere, monkeypatch):
    (elsewhere / "models").mkdir()
    monkeypatch.setenv(paths.MODELS_ENV, str(elsewhere / "mine"))
    assert paths.models_dir() == elsewhere / "mine"
    assert _default_models(demo) == str(elsewhere / "mine")
    monkeypatch.setenv(paths.MODELS_ENV, "")  # empty: unset
    assert paths.models_dir() == Path("models")


def test_the_option_still_overrides(elsewhere, monkeypatch):
    monkeypatch.setenv(paths.MODELS_ENV, str(elsewhere / "mine"))
    with evaluate.make_context("evaluate", ["--out", "unused", "--models", "given"]) as ctx:
        assert ctx.params["models"] == "given"
