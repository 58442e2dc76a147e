"""`vacc train --help`: generated from Config's field docstrings, short enough to read."""

from __future__ import annotations

import dataclasses

from click.testing import CliRunner

from agent_client.rl.cli import field_docs, option_name, train
from agent_client.rl.config import Config
from vacc.cli import main

HELP_LIMIT = 10_000  # [characters] the whole of `vacc train --help`
OPTION_HELP_LIMIT = 300  # [characters] one option's help; the evidence lives in docs/training.md and docs/options.md


def test_the_train_help_is_short_and_every_option_says_what_it_does_briefly():
    result = CliRunner().invoke(main, ["train", "--help"])
    assert result.exit_code == 0, result.output
    assert len(result.output) < HELP_LIMIT
    for p in train.params:
        assert p.help, p.name  # every option says what it does
        assert len(p.help) <= OPTION_HELP_LIMIT, (p.name, len(p.help))


def test_every_config_field_is_an_option_with_its_docstring_as_help():
    docs = field_docs()
    options = {p.name: p for p in train.params}
    for f in dataclasses.fields(Config):
        assert docs[f.name] and options[f.name].help == docs[f.name]
        assert options[f.name].opts == [option_name(f.name)]  # the option names do not change


def test_the_schedule_help_and_its_default_agree():
    result = CliRunner().invoke(main, ["train", "--help"])
    assert Config().schedule == "serial" and "[default: serial]" in result.output
    assert "parallel" not in (train.help or "")  # the command's text once called parallel the default


def test_train_config_file_gives_the_defaults_and_options_override_them(tmp_path, monkeypatch):
    import json
    from pathlib import Path

    import agent_client.rl.train as single
    from agent_client.rl.config import config_dict

    seen: list[Config] = []

    def fake_training(cfg: Config, out: str, resume: bool = False, progress: bool = True) -> dict:
        seen.append(cfg)
        Path(out).mkdir(parents=True, exist_ok=True)
        return {"steps": 0, "episodes": 0, "wall_s": 0.0, "last_eval": []}

    monkeypatch.setattr(single, "train", fake_training)
    saved = config_dict(Config(reward="eco", action="ramp-fine", teacher="eco-margin", decision="mean", seed=7, total_steps=10))
    (tmp_path / "config.json").write_text(json.dumps(saved))
    args = ["train", "--config", str(tmp_path / "config.json"), "--out", str(tmp_path / "run"), "--quiet"]
    result = CliRunner().invoke(main, [*args, "--decision-brake-share", "0.4"])
    assert result.exit_code == 0, result.output
    assert config_dict(seen[0]) == {**saved, "decision_brake_share": 0.4}
    bad = CliRunner().invoke(main, [*args, "--gamma", "1.0"])
    assert bad.exit_code == 2 and "--gamma" in bad.output  # the error names the option
