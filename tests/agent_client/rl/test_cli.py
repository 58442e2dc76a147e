"""`vacc train --help`: generated from Config's field docstrings, short enough to read."""

from __future__ import annotations

import dataclasses

from click.testing import CliRunner

from agent_client.rl.cli import field_docs, option_name, train
from agent_client.rl.config import Config
from vacc.cli import main

HELP_LIMIT = 10_000  # [characters] the whole of `vacc train --help`
OPTION_HELP_LIMIT = 300  # [characters] one option's help; the evidence lives in docs/training.md


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
