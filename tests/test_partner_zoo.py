"""The zoo of named partners (``sidewalk.partners.zoo``, ``sidewalk-partners``): every learned and scripted partner
named; its card a Hugging Face model card whose facts are those of README.md and the recorded result files; a learned
policy exported to ONNX acting as torch does in onnxruntime; ``opponent=zoo`` in training, cross-play and the play
page; bad input refused with one ``error:`` line before any work."""

from __future__ import annotations

import json
import re
import runpy
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
import yaml

from sidewalk.partners import cards, zoo
from sidewalk.partners.policy import OBSERVATION_KEY, PolicyOpponent, read_partner
from sidewalk.partners.population import POPULATIONS

ROOT = Path(__file__).resolve().parents[1]
PARTNERS = ROOT / "sidewalk" / "partners"
RESULTS = ROOT / "results" / "reference"
LEARNED = sorted(f"{path.parent.parent.name}/{path.parent.name}" for path in PARTNERS.glob("*/*/policy.pt"))
partners_cli = runpy.run_path(str(ROOT / "runners" / "partners.py"))["main"]


def run(capsys, *argv: str) -> tuple[int, str, str]:
    status = partners_cli(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


# ---- names and cards --------------------------------------------------------------------------------------------


def test_list_names_every_learned_partner_over_both_domains_and_every_scripted_one(capsys):
    status, out, err = run(capsys, "list")
    assert status == 0, err
    listed = [line.split()[0] for line in out.splitlines()]
    assert listed == list(zoo.partners())
    assert [name for name in listed if "/" in name] == LEARNED  # every shipped policy.pt, both domains
    assert {name.split("/")[0] for name in LEARNED} == {"discrete", "continuous"}
    scripted = {member_name for populations in POPULATIONS.values() for table in populations.values()
                for member_name, member in table.items() if member.opponent != "policy"}
    assert {name for name in listed if "/" not in name} == scripted | {"random"}
    line = dict(zip(listed, out.splitlines()))
    assert "heldout" in line["discrete/vdn_seed0"] and "training" in line["discrete/iql_seed0"]
    assert "team success with itself: 0.879" in line["discrete/iql_seed0"]
    assert "not measured" in line["keep_left_wide"]


@pytest.mark.parametrize("name", ["discrete/vdn_seed3", "continuous/ippo_seed0", "keep_left", "random"])
def test_show_prints_a_hugging_face_model_card(capsys, name):
    status, out, err = run(capsys, "show", name)
    assert status == 0, err
    match = re.fullmatch(r"---\n(?P<header>.*?)\n---\n(?P<body>.*)", out, re.DOTALL)
    assert match, out[:500]
    header = yaml.safe_load(match["header"])
    assert header["license"] == "mit"  # pyproject's license, as the Hub names it
    assert {"sidewalk-problem", "ad-hoc-teamwork"} <= set(header["tags"])
    body = match["body"]
    assert f"# {name}\n" in body and "## Scores" in body and "## Use" in body
    assert "| the scripted partners |" in body and "not measured" in body  # recorded nowhere: said so
    for result in header.get("model-index", [{}])[0].get("results", []):
        assert result["metrics"][0]["type"] == "team_success" and result["metrics"][0]["verified"] is False


def test_a_cards_scores_and_training_are_the_recorded_ones():
    card = cards.card("discrete/vdn_seed0")
    assert "| command | `python runners/main.py +experiment=selfplay_discrete algo=vdn" in card
    assert "| commit | 01fff99 |" in card and "| split (discrete) | held out" in card
    assert "| itself | discrete | 0 | 0.898 | 0 | 256 |" in card
    assert "| iql self-play | discrete | 0 |" in card  # its cross-play cells with the IQL learners
    assert "| learners | discrete, continuous | | not measured |" in cards.card("keep_left_wide")


# ---- the facts: one file, held equal to README.md and the results it cites ---------------------------------------


def readme_rows() -> dict[str, dict[str, str]]:
    """sidewalk/partners/README.md's table, by partner."""
    rows = {}
    for line in (PARTNERS / "README.md").read_text().splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("| `") and len(cells) == 6:
            name, split, command, commit, wall_clock, itself = cells
            rows[name.strip("`")] = {"split": split, "command": command.strip("`"), "commit": commit,
                                     "wall_clock": wall_clock, "itself": itself}
    return rows


def test_the_recorded_scores_are_those_of_the_result_files_they_cite():
    recorded = cards.recorded_scores(RESULTS)
    assert {"continuous/mappo_seed0", "discrete/vdn_seed3", "keep_left", "dijkstra", "prm", "random"} <= set(recorded)
    in_yaml = {name: [score for score in entry.scores() if score["source"] != cards.README_SOURCE]
               for name, entry in zoo.partners().items()}
    assert {name: scores for name, scores in in_yaml.items() if scores} == recorded, (
        "zoo.yaml's scores are not the results'; after re-making a reference table: "
        "python -m sidewalk.partners.cards results/reference")


def test_readme_and_the_cards_say_the_same_of_each_learned_partner():
    rows = readme_rows()
    assert sorted(rows) == LEARNED
    for name in LEARNED:
        entry, row = zoo.partner(name), rows[name]
        trained = entry.facts["trained"]
        assert (row["command"], row["commit"]) == (trained["command"], trained["commit"]), name
        assert row["wall_clock"] == trained.get("wall_clock", "not recorded"), name
        assert row["split"] == cards.split_text(entry), name
        itself = [score for score in entry.scores() if score["with"] == "itself"]
        assert len(itself) == 1 and itself[0]["source"] == "sidewalk/partners/README.md", name
        assert row["itself"] == f"{itself[0]['team_success'][0]:.3f}", name
        saved = read_partner(entry.folder)
        assert itself[0]["noise"] == saved.world.env_params.noise and trained["seed"] == int(name[-1]), name
    assert set(zoo.facts()["partners"]) <= set(zoo.partners())  # no card facts of a partner that is not in the zoo


# ---- export ------------------------------------------------------------------------------------------------------


def observed(name: str, worlds: int = 256, steps: int = 6) -> tuple[PolicyOpponent, dict]:
    """The partner as it plays agent 1 in its own world, and that world's core outputs after random steps (so
    that the observations differ): what torch's policy acts on."""
    saved = read_partner(zoo.partner(name).folder)
    core = saved.world.core(worlds, seed=0)
    out = core.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(steps):
        action = core.full_action_spec["agents", "action"]
        if saved.world.domain == "discrete":
            joint = torch.randint(0, 4, action.shape, generator=generator)
        else:
            joint = (torch.rand(action.shape, generator=generator) * 2 - 1) * action.space.high
        out = core.step(out.set(("agents", "action"), joint))["next"]
    return PolicyOpponent(core, controlled=(1,), ego=0, path=zoo.partner(name).folder), out


@pytest.mark.parametrize("name", LEARNED)  # ~2 s each
def test_an_exported_policy_acts_in_onnxruntime_as_torch_does(capsys, tmp_path, name):
    import onnx
    import onnxruntime

    path = tmp_path / "partner.onnx"
    status, _, err = run(capsys, "export", name, "--format", "onnx", "--out", str(path))
    assert status == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["partner.onnx"]  # one file, its weights inside
    opponent, out = observed(name)
    with torch.no_grad():
        expected = opponent(out.clone()).get(("agents", "action"))[:, 1].numpy()
    observation = out.get(OBSERVATION_KEY)[:, 1].numpy()
    assert len(np.unique(observation, axis=0)) > 16  # 256 worlds a few steps in: many observations
    session = onnxruntime.InferenceSession(str(path))
    actions = session.run(["action"], {"observation": observation})[0]
    if expected.dtype.kind == "f":  # continuous: (acceleration, turn), float32 arithmetic in two runtimes
        np.testing.assert_allclose(actions, expected, atol=1e-5)
    else:  # the grid's moves, argmax of the same Q-values
        np.testing.assert_array_equal(actions, expected)
    # What the file says of itself is what the Gymnasium face needs: its observation goes straight in.
    metadata = {prop.key: prop.value for prop in onnx.load(str(path)).metadata_props}
    assert metadata["sidewalk.partner"] == name and metadata["license"] == "mit"
    env = gymnasium.make(metadata["sidewalk.gymnasium_id"], **json.loads(metadata["sidewalk.gymnasium_kwargs"]))
    first, _ = env.reset(seed=0)
    action = session.run(["action"], {"observation": first[None]})[0][0]
    assert env.action_space.contains(action.astype(env.action_space.dtype))
    env.step(action)


# ---- one config choice: training, cross-play, the play page ------------------------------------------------------


def test_opponent_zoo_trains_a_tiny_run(processes, tmp_path):
    overrides = ["opponent=zoo", "opponent.params.name=discrete/vdn_seed0", "iterations=2", "num_envs=4",
                 "eval_every=2", "eval_episodes=4", "checkpoint_every=0", "logger=none", "plots=false",
                 "algo.frames_per_batch=16", "algo.batch_size=16", "algo.learning_starts=0",
                 "algo.updates_per_batch=1", "env.max_steps=30", f"hydra.run.dir={tmp_path / 'run'}"]
    result = processes.run("runners/main.py", *overrides, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    config = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert config["opponent"]["name"] == "zoo" and config["opponent"]["params"] == {"name": "discrete/vdn_seed0"}
    assert (tmp_path / "run" / "metrics.csv").exists()


@pytest.mark.parametrize("overrides, said", [
    (["opponent.params.name=discrete/vdn_seed9"], "opponent.params.name='discrete/vdn_seed9' is not a zoo partner"),
    (["opponent.params.name=continuous/mappo_seed0"], "plays the continuous domain, not discrete"),
    (["env=continuous", "opponent.params.name=dijkstra"], "plays the discrete domain, not continuous"),
    ([], "opponent.params.name=None is not a zoo partner"),
])
def test_a_bad_zoo_name_is_refused_naming_the_valid_ones(overrides, said):
    from sidewalk.compose import compose
    from sidewalk.hydra_callbacks import checked

    with pytest.raises(ValueError, match=re.escape(said)) as refused:
        checked(compose(["opponent=zoo", *overrides]))
    assert re.search(r"; valid( in the \w+ domain)?: ", str(refused.value)) and "keep_left" in str(refused.value)


def test_cross_play_takes_zoo_partners_learned_and_scripted():
    from sidewalk.crossplay import run_crossplay
    from sidewalk.crossplay.players import CrossplayError

    matrix = run_crossplay([str(PARTNERS / "discrete" / "iql_seed0")], "zoo:discrete/vdn_seed0,zoo:keep_left",
                           episodes=4, seed=0, show_progress=False)
    cells = matrix.frame.set_index("partner")
    assert list(cells.index) == ["zoo:discrete/vdn_seed0", "zoo:keep_left"]
    assert list(cells["partner_kind"]) == ["learned", "scripted"]
    with pytest.raises(CrossplayError, match=r"'nosuch' is not a zoo partner of the discrete domain; valid: .*iql"):
        run_crossplay([str(PARTNERS / "discrete" / "iql_seed0")], "zoo:nosuch", episodes=4, show_progress=False)


def test_the_play_page_plays_a_zoo_partner():
    from sidewalk.play.command import compose_game_world
    from sidewalk.play.game import Game

    world = compose_game_world(["opponent=zoo", "opponent.params.name=discrete/vdn_seed1"])
    assert (world.opponent, dict(world.opponent_params)) == ("zoo", {"name": "discrete/vdn_seed1"})
    game = Game(world, None, seed=0)
    assert game.describe()["partner_settings"] == {"name": "discrete/vdn_seed1"}


# ---- bad input ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("argv, said", [
    (["show", "nosuch"], "partner='nosuch' is not a zoo partner; valid: continuous/ippo_seed0, "),
    (["export", "keep_left", "--out", "x.onnx"],
     "'keep_left' is scripted: only a learned partner's policy exports; learned partners: continuous/ippo_seed0, "),
    (["export", "nosuch", "--out", "x.onnx"], "partner='nosuch' is not a zoo partner; valid: "),
    (["export", "discrete/iql_seed0", "--format", "tflite", "--out", "x.onnx"],
     "--format='tflite' is not valid; valid: 'onnx'"),
    (["export", "discrete/iql_seed0", "--out", "no/such/folder/x.onnx"], "its folder 'no/such/folder' does not exist"),
    (["export", "discrete/iql_seed0", "--agent", "2", "--out", "x.onnx"], "--agent=2 is not valid; valid: 0, 1"),
])
def test_bad_input_is_one_error_line_and_exit_2_before_any_work(capsys, monkeypatch, tmp_path, argv, said):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(zoo, "export_onnx", lambda *args, **kwargs: pytest.fail("exported despite bad input"))
    status, out, err = run(capsys, *argv)
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: ") and said in err, err
    assert list(tmp_path.iterdir()) == []
