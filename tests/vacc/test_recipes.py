"""Recipes: every shipped one parses; a bad one is refused in one line naming the file and the key."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from vacc.recipes import (
    LATE_OPTIONS,
    RECIPES_DIR,
    RecipeError,
    digest,
    load_recipe,
    parse_recipe,
    stage_config,
    stage_refs,
)

RECIPES = sorted(p.stem for p in RECIPES_DIR.glob("*.toml"))
EV_FORCE_CHAIN = Path(__file__).parent / "data" / "ev-force-chain.toml"  # a chain of four train stages
SHIPPED = ("ice-gap", "ice-force", "ice-eco", "ev-gap", "ev-force", "ev-eco")


def test_there_is_a_recipe_for_every_shipped_model():
    assert set(SHIPPED) <= set(RECIPES)


@pytest.mark.parametrize("name", RECIPES)
def test_every_recipe_parses_and_names_only_earlier_stages(name):
    recipe = load_recipe(name)
    assert recipe.name == name and recipe.stages and recipe.gates["tests"]["max_gap_rmse_m"] > 0
    seen: set[str] = set()
    for stage in recipe.stages:
        assert set(stage_refs(stage)) <= seen
        if stage.kind == "train":
            assert stage_config(stage).total_steps > 0
        seen.add(stage.name)


def test_the_last_train_stages_are_the_shipped_checkpoints_settings():
    from agent_client.rl.checkpoint import checkpoint_config, read_checkpoint
    from agent_client.rl.config import config_dict

    models = Path(__file__).resolve().parents[2] / "models"
    chains = (("ice-gap", "stop", "final"), ("ev-force", "seed-b", "ice-force"), ("ice-force", "long", "ice-gap"), ("ice-eco", "busy-road", "sg-decide"),
              ("ev-gap", "stop", "ice-gap"), ("ev-eco", "dagger", "ev-gap"))  # fmt: skip
    for name, stage, parent in chains:
        path = models / f"{name}.pt"
        shipped = config_dict(checkpoint_config(read_checkpoint(path), path))
        cfg = config_dict(stage_config(load_recipe(name).stage(stage), {parent: shipped["init_from"]}))
        assert cfg == shipped, name


def test_digest_is_of_the_content_not_the_layout(tmp_path):
    text = EV_FORCE_CHAIN.read_text()
    content = tomllib.loads(text)
    for stage in content["stage"]:
        stage.pop("known_weights", None)  # an outcome, left out (below)
        stage.pop("cpu_path", None)  # the kernels: the same stage on any, left out
        for late in LATE_OPTIONS:  # options added late, at their inert values: left out
            stage.pop(late, None)
    a = digest(content)
    assert a == load_recipe(EV_FORCE_CHAIN).digest
    assert parse_recipe(tomllib.loads("# a comment\n" + text), Path("x.toml")).digest == a
    assert parse_recipe(tomllib.loads(text.replace("seed = 72", "seed = 73")), Path("x.toml")).digest != a


def test_the_cpu_path_is_checked_defaults_to_avx2_and_is_left_out_of_the_digest():
    c = _content()
    plain = parse_recipe(c, Path("recipes/x.toml"))
    c["recipe"]["cpu_path"] = "native"
    native = parse_recipe(c, Path("recipes/x.toml"))
    assert (plain.cpu_path, native.cpu_path) == ("avx2", "native") and plain.digest == native.digest  # how it runs, not what it is
    c["recipe"]["cpu_path"] = "avx1024"
    _refuse(c, "recipe.cpu_path", "'avx1024' is not one of avx2, avx512, native")
    c = _content()
    c["stage"][1]["cpu_path"] = "avx512"  # a stage made on other kernels than the recipe's
    staged = parse_recipe(c, Path("recipes/x.toml"))
    assert staged.stages[1].cpu_path == "avx512" and staged.stages[0].cpu_path is None and staged.digest == plain.digest
    c["stage"][1]["cpu_path"] = "avx1024"
    _refuse(c, "stage 'ev-gap'.cpu_path", "a train stage's kernels")


def test_reseed_from_names_a_stage_and_is_in_the_digest():
    c = _content()
    plain = parse_recipe(c, Path("recipes/x.toml"))
    c["recipe"]["reseed_from"] = "mix"
    tail = parse_recipe(c, Path("recipes/x.toml"))
    assert (plain.reseed_from, tail.reseed_from) == (None, "mix") and plain.digest != tail.digest  # it says what --seed N makes
    c["recipe"]["reseed_from"] = "nowhere"
    _refuse(c, "recipe.reseed_from", "'nowhere' is no stage")


@pytest.mark.parametrize(("late", "other"), [("critic_warmup", 500), ("actor_levels", "ramp"), ("emergency", "stopping")])
def test_an_option_added_late_leaves_digests_and_keys_alone_at_its_inert_value(late, other):
    """critic_warmup and actor_levels came after the recipes were digested: written in at
    their inert values they change no digest and no stage key (runs and --reuse stay valid);
    any other value is a new stage."""
    from vacc.reproduce import stage_key

    c = _content()
    r = parse_recipe(c, Path("recipes/x.toml"))
    assert all(s.options[late] == LATE_OPTIONS[late] for s in r.stages if s.kind == "train")
    for stage in c["stage"]:
        stage.pop(late, None)
    assert digest({**c, "stage": [{k: v for k, v in st.items() if k not in ("known_weights", "cpu_path", *LATE_OPTIONS)} for st in c["stage"]]}) == r.digest
    opts = {"seed": r.seed, "smoke": False, "reseed_from": None}
    mix = r.stage("mix")
    changed = mix._replace(options={**mix.options, late: other})
    assert stage_key(r, mix, opts, []) == stage_key(r, mix._replace(options={k: v for k, v in mix.options.items() if k != late}), opts, [])
    assert stage_key(r, changed, opts, []) != stage_key(r, mix, opts, [])
    c = _content()
    c["stage"][-1][late] = other
    _refuse(c, "stage 'mix'", late)  # not a continuous stage: refused


def _content() -> dict:
    return tomllib.loads(EV_FORCE_CHAIN.read_text())


def _refuse(content: dict, *words: str) -> None:
    with pytest.raises(RecipeError) as info:
        parse_recipe(content, Path("recipes/x.toml"))
    message = str(info.value)
    assert "\n" not in message and message.startswith("recipes/x.toml: ")
    for w in words:
        assert w in message, message


def test_unknown_key_is_refused():
    c = _content()
    c["stage"][1]["learning_rat"] = 1e-4
    _refuse(c, "stage 'ev-gap'.learning_rat", "unknown key")
    c = _content()
    c["recipe"]["seeds"] = 3
    _refuse(c, "recipe.seeds", "unknown key")
    c = _content()
    c["gates"]["tests"]["max_rmse"] = 3
    _refuse(c, "gates.tests.max_rmse")


def test_missing_option_is_refused():
    c = _content()
    del c["stage"][0]["gamma"]
    _refuse(c, "stage 'gap-scratch'.gamma", "missing")


def test_unknown_stage_reference_is_refused():
    c = _content()
    c["stage"][1]["init_from"] = "stage:nowhere"
    _refuse(c, "stage 'ev-gap'.init_from", "'stage:nowhere'", "names no earlier stage")


def test_a_cycle_is_refused():
    c = _content()
    c["stage"][1]["init_from"] = "stage:ev-force"  # a later stage
    _refuse(c, "stage 'ev-gap'.init_from", "cycle")
    c = _content()
    c["stage"][1]["init_from"] = "stage:ev-gap"
    _refuse(c, "names its own stage (a cycle)")


def test_a_path_where_a_stage_is_required_is_refused():
    c = _content()
    c["stage"][1]["init_from"] = "models/ice-gap.pt"
    _refuse(c, "stage 'ev-gap'.init_from", "is not a stage reference", "a path")


def test_bad_values_are_refused_naming_the_key():
    c = _content()
    c["stage"][0]["kind"] = "distill"
    _refuse(c, "stage 'gap-scratch'.kind", "'distill'")
    c = _content()
    c["stage"][0]["gamma"] = 1.5
    _refuse(c, "stage 'gap-scratch'.gamma")
    c = _content()
    c["stage"][0]["output"] = "eval:100"
    _refuse(c, "stage 'gap-scratch'.output") if not c["stage"][0]["keep_evals"] else None
    c = _content()
    c["stage"][0]["output"] = "swa:many"
    _refuse(c, "stage 'gap-scratch'.output", "is not best, latest, eval:STEP or swa:STEP")
    c = _content()
    c["stage"][0].update(output="swa:100", keep_evals=False)
    _refuse(c, "stage 'gap-scratch'.output", "needs keep_evals = true")
    c = _content()
    c["stage"][0].update(output=f"swa:{c['stage'][0]['total_steps']}", keep_evals=True, eval_every=1000)
    _refuse(c, "stage 'gap-scratch'.output", "STEP below total_steps")
    c = _content()
    c["stage"][0].update(output="swa:100", keep_evals=True, eval_every=1000)
    parse_recipe(c, EV_FORCE_CHAIN)  # the tail's mean, well formed
    c = _content()
    c["stage"][1]["name"] = "gap-scratch"
    _refuse(c, "another stage has this name")
    c = _content()
    c["gates"]["safety"]["scenarios"] = ["stopped", "moon-landing"]
    _refuse(c, "gates.safety.scenarios", "moon-landing")
    c = _content()
    c["recipe"]["scenario"] = "truck"
    _refuse(c, "recipe.scenario")


def test_surgery_stages_are_checked():
    c = _content()
    c["stage"].append({"name": "soup", "kind": "average", "inputs": ["stage:mix"], "weights": [1.0]})
    _refuse(c, "stage 'soup'.inputs", "two or more")
    c = _content()
    c["stage"].append({"name": "soup", "kind": "average", "inputs": ["stage:mix", "stage:ev-gap"], "weights": [1.0]})
    _refuse(c, "stage 'soup'.weights")
    c = _content()
    c["stage"].append({"name": "d", "kind": "decide", "input": "stage:mix", "decision": "median", "temperature": 2.0, "brake_share": 1.0,
                       "brake_confirm": 1, "full_brake_confirm": 1, "deadband": 0.0, "smoothing": 1.0})
    _refuse(c, "stage 'd'.decision", "'median'")


def test_a_missing_recipe_is_named(tmp_path):
    with pytest.raises(RecipeError, match="neither a recipe file nor a recipe"):
        load_recipe("no-such-model")
    bad = tmp_path / "bad.toml"
    bad.write_text("[recipe\n")
    with pytest.raises(RecipeError, match="not valid TOML"):
        load_recipe(bad)


def test_known_weights_are_checked_and_left_out_of_the_digest():
    c = _content()
    plain = parse_recipe(c, Path("recipes/x.toml"))
    c["stage"][0]["known_weights"] = "ab" * 32
    known = parse_recipe(c, Path("recipes/x.toml"))
    assert known.stages[0].known_weights == "ab" * 32 and plain.stages[0].known_weights is None
    assert known.digest == plain.digest  # an outcome written in later does not invalidate a run
    for bad in ("AB" * 32, "ab" * 31, 7):
        c["stage"][0]["known_weights"] = bad
        _refuse(c, f"stage '{c['stage'][0]['name']}'.known_weights", "SHA-256")


def test_ice_gap_names_the_weights_of_its_shipped_history():
    recipe = load_recipe("ice-gap")
    known = {s.name for s in recipe.stages if s.known_weights}
    assert {"scratch", "final"} <= known


def test_a_shipped_stage_names_a_model_and_its_weights():
    c = tomllib.loads((RECIPES_DIR / "ice-eco-ac.toml").read_text())
    r = parse_recipe(c, Path("x.toml"))
    assert r.stages[0].kind == "shipped" and stage_refs(r.stages[0]) == [] and stage_refs(r.stages[1]) == ["ice-eco"]
    c["stage"][0]["weights_sha256"] = "abc"
    _refuse(c, "stage 'ice-eco'.weights_sha256", "not a SHA-256")
    c = tomllib.loads((RECIPES_DIR / "ice-eco-ac.toml").read_text())
    c["stage"][0]["model"] = "../models/ice-eco"
    _refuse(c, "stage 'ice-eco'.model", "not a shipped model's name")
