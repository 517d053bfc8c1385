"""One World: the value every face describes a world with someone in it by. It round-trips as plain data, builds the
env training builds, says what differs from another, and reads the policy.pt files written before it existed."""

from __future__ import annotations

import ast
import dataclasses
import json
import re
from pathlib import Path

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from sidewalk.compose import compose_experiment
from sidewalk.envs import CORE_ENVS, ContinuousParams, DiscreteParams, core_class
from sidewalk.partners.policy import read_partner
from sidewalk.partners.population import PARTNERS_DIR
from sidewalk.run_folder import saved_world
from sidewalk.world import MAY_DIFFER, World

PACKAGE = Path(__file__).resolve().parents[1] / "sidewalk"


def test_a_world_round_trips_as_plain_data():
    worlds = [
        World("discrete", DiscreteParams(noise=0.1, start_jitter_rows=1), "dijkstra", {"tie_break": "progress"},
              ego=1, end_on_ego_done=True, shield=True),
        World("continuous", ContinuousParams(layout="circle", n_agents=4), "self", other_play=False),
    ]
    for world in worlds:
        plain = json.loads(json.dumps(world.to_dict()))
        assert World.from_dict(plain) == world
        assert world.core_class is CORE_ENVS[world.domain]


def test_a_world_written_before_a_later_env_key_reads_as_the_world_it_was():
    written = World("discrete", DiscreteParams()).to_dict()
    del written["env_params"]["start_jitter_rows"], written["env_params"]["cost"]
    assert World.from_dict(written) == World("discrete", DiscreteParams(start_jitter_rows=0, cost="collision"))
    with pytest.raises(ValueError, match="a world has no opponnent"):
        World.from_dict({**written, "opponnent": "prm"})
    with pytest.raises(ValueError, match="domain='grid' is not one of discrete, continuous"):
        core_class("grid")


def test_the_experiment_trains_and_evaluates_on_its_worlds():
    experiment = compose_experiment(["noise=0.1"])
    train, evaluation = experiment.world, experiment.eval_world
    assert (train.domain, train.opponent, train.env_params.noise) == ("discrete", "dijkstra", 0.1)
    # The default protocol perturbs evaluation and training alike: the two worlds differ in nothing.
    assert evaluation.differences(train) == []
    nominal = compose_experiment(["eval=nominal", "noise=0.1"])
    assert nominal.eval_world.env_params.start_jitter_rows == 0
    assert compose_experiment(["eval.train_alike=false"]).eval_world.differences(
        compose_experiment(["eval.train_alike=false"]).world) == ["env.start_jitter_rows", "env.goal_jitter_rows"]
    view = train.make(4, seed=0)
    check_env_specs(view)
    assert view.core.params == train.env_params and view.batch_size == torch.Size([4])


def test_differences_name_what_separates_two_worlds():
    world = World("discrete", DiscreteParams())
    other = world.replace(noise=0.2, opponent="dijkstra", layout="door", n_agents=3)
    assert world.differences(other) == ["env.layout", "env.n_agents", "env.noise", "opponent"]
    assert world.differences(other, ignoring=MAY_DIFFER) == ["env.layout", "env.n_agents", "opponent"]
    assert world.differences(World("continuous", ContinuousParams())) == ["domain"]
    with pytest.raises(TypeError, match="must be a ContinuousParams"):
        World("continuous", DiscreteParams())


def test_a_stand_in_world_has_the_specs_without_building_the_partner():
    world = World("continuous", ContinuousParams(), "prm", {"roadmap_seed": 3}, ego=1, shield=True)
    stand_in = world.stand_in()
    assert (stand_in.opponent, stand_in.opponent_params, stand_in.ego, stand_in.shield) == ("random", {}, 1, False)
    built, own = stand_in.make(1), world.make(1)
    assert built.observation_spec["observation"] == own.observation_spec["observation"]
    assert built.full_action_spec == own.full_action_spec
    selfplay = World("discrete", DiscreteParams(), "self", other_play=True)
    assert selfplay.stand_in().opponent == "self"


def test_the_shipped_partners_written_before_the_world_read_as_worlds():
    """The shipped partners' policy.pt files describe their world in the older form (domain, env_params, opponent,
    ego); they read as the World a policy.pt written today describes."""
    for member in ("discrete/iql_seed0", "continuous/mappo_seed1"):
        file = PARTNERS_DIR / member / "policy.pt"
        described = torch.load(file, weights_only=True)["description"]
        assert "world" not in described  # the older form: the test would pass vacuously on a re-written file
        algo_name, _, world = saved_world(described, file.parent)
        assert (algo_name, world.opponent, world.domain) == (member.split("/")[1].split("_")[0], "self",
                                                               member.split("/")[0])
        assert World.from_dict(world.to_dict()) == world
        assert read_partner(file.parent).world == world


def test_a_run_folder_from_before_policy_pt_described_itself_reads_its_world(tmp_path):
    """The oldest form: a policy.pt with networks only; the world comes from the folder's config.yaml."""
    from omegaconf import OmegaConf

    from sidewalk.compose import compose

    cfg = compose(["opponent=dijkstra", "noise=0.1"])
    OmegaConf.save(cfg, tmp_path / "config.yaml", resolve=True)
    algo_name, algo, world = saved_world(None, tmp_path)
    assert (algo_name, world.opponent, world.env_params.noise) == ("dqn", "dijkstra", 0.1)
    assert algo["name"] == "dqn"


def _source_lines(pattern: str) -> list[str]:
    found = []
    for path in PACKAGE.rglob("*.py"):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(pattern, line):
                found.append(f"{path.relative_to(PACKAGE)}:{number}")
    return found


def test_a_domain_maps_to_its_core_class_in_one_place():
    """``sidewalk.envs.CORE_ENVS`` is the one map; a second (``X if domain == "discrete" else Y``, a dict of the two
    classes) would drift from it."""
    assert _source_lines(r"DiscreteSidewalkEnv if|else DiscreteSidewalkEnv|\"discrete\": DiscreteSidewalkEnv") == [
        "envs/__init__.py:" + str(next(number for number, line in enumerate(
            (PACKAGE / "envs/__init__.py").read_text().splitlines(), 1) if "CORE_ENVS: dict" in line))]


def test_no_signature_spells_out_the_world_s_keyword_group():
    """The world's settings travel as a World, not as the four keywords (opponent, ego, end_on_ego_done,
    opponent_kwargs) in one more signature; the views, which a World builds, and the Gymnasium face's keywords are
    where they are spelled."""
    allowed = {"views/__init__.py", "views/ego.py", "interop/gymnasium.py", "interop/pettingzoo.py"}
    group = {"opponent", "ego", "end_on_ego_done", "opponent_kwargs"}
    spelled = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names = {a.arg for a in (*node.args.args, *node.args.kwonlyargs)}
                if group <= names and str(path.relative_to(PACKAGE)) not in allowed:
                    spelled.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}")
    assert not spelled, spelled


def test_world_fields_are_the_experiment_s_world_settings():
    """What config.validate reads into a World is every setting of one (a new World field must reach training)."""
    fields = {f.name for f in dataclasses.fields(World)}
    assert fields == {"domain", "env_params", "opponent", "opponent_params", "ego", "end_on_ego_done", "shield",
                      "other_play", "role_frame"}


# Written at da5af71, before the World: a DQN run folder (config.yaml, policy.pt, summary.json, ...) and a Minari
# dataset of three Dijkstra walks (tests/fixtures/before_world/).
BEFORE_WORLD = Path(__file__).resolve().parent / "fixtures" / "before_world"


def test_a_run_folder_written_before_the_world_replays_as_a_partner():
    run = BEFORE_WORLD / "dqn_run"
    assert "world" not in torch.load(run / "policy.pt", weights_only=True)["description"]
    partner = read_partner(run)
    assert (partner.algo_name, partner.world.opponent, partner.world.env_params.observation) == (
        "dqn", "dijkstra", "vector")
    world = World("discrete", partner.world.env_params, "policy", {"path": str(run)})
    rollout = world.make(4, seed=0).rollout(8, break_when_any_done=False)
    assert rollout.get(("next", "done")).shape == (4, 8, 1)


def test_a_report_reads_a_run_folder_written_before_the_world():
    from sidewalk.report.runs import find_run_folders, load_run

    (folder,) = find_run_folders([BEFORE_WORLD / "dqn_run"])
    run = load_run(folder)
    assert run.summary["seed"] == 0 and len(run.metrics) == 2


def test_a_dataset_written_before_the_world_loads_without_a_mismatch(recwarn):
    pytest.importorskip("minari")
    from sidewalk import datasets

    dataset = datasets.load("sidewalk/fixture-walks-v0", data_path=BEFORE_WORLD / "datasets")
    assert dataset.total_episodes == 3
    assert not [w for w in recwarn if issubclass(w.category, datasets.DatasetEnvMismatchWarning)]
    pins = datasets.pins_of(dataset)
    assert (pins["env_config"]["opponent"], pins["env_config"]["noise"]) == ("dijkstra", 0.1)


@pytest.mark.parametrize("domain, keys", [("discrete", ("start_jitter_rows", "goal_jitter_rows")),
                                          ("continuous", ("start_jitter_m", "goal_jitter_m", "heading_jitter_rad"))])
def test_each_face_states_its_default_worlds_and_the_runner_s(domain, keys):
    """The faces draw the scenario's own worlds by default; each says so first and names the runner's protocol's
    bounds, which are what the main job evaluates on (read from the composed default config, so they cannot drift)."""
    import sidewalk.interop.gymnasium as gym_face
    import sidewalk.interop.pettingzoo as zoo_face

    evaluated = compose_experiment([f"env={domain}"]).eval_world.env_params
    stated = ", ".join(f"{key}={getattr(evaluated, key):g}" for key in keys)
    guide = (PACKAGE.parent / "docs" / "guide" / "envs.md").read_text().split("\n\n")[1]
    for face in (gym_face.__doc__.split("\n\n")[1], zoo_face.__doc__.split("\n\n")[1], guide):
        assert "the scenario's own starts and goals" in face
        assert stated in " ".join(face.split()).replace("``", "").replace("`", "")
    assert World(domain, core_class(domain).Params()).env_params.__getattribute__(keys[0]) == 0


def test_the_outcome_flags_and_their_words_are_listed_once():
    """``envs.base.OUTCOME_WORDS`` (and ``INFO_KEYS``, its keys) is the one list: no other literal of the package
    names two or more of the flags (a second list would drift from it; one flag read by name is a fact of its own)."""
    from sidewalk.envs import INFO_KEYS

    lists = []
    for path in PACKAGE.rglob("*.py"):
        if path.relative_to(PACKAGE).as_posix() == "envs/base.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            items = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else (
                node.keys if isinstance(node, ast.Dict) else [])
            named = {item.value for item in items if isinstance(item, ast.Constant) and item.value in INFO_KEYS}
            if len(named) >= 2:
                lists.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not lists, lists


def test_the_gymnasium_face_builds_the_world_its_keywords_describe():
    """World → gymnasium.make keywords (``world_kwargs``) → the face's World: the same value, which a dataset's pins
    are written from."""
    import gymnasium

    from sidewalk.interop.gymnasium import ENV_IDS, world_kwargs

    world = World("discrete", DiscreteParams(noise=0.1, start_jitter_rows=1, goal_jitter_rows=1), "dijkstra",
                  {"tie_break": "progress"}, ego=1, end_on_ego_done=True)
    face = gymnasium.make(ENV_IDS["discrete"], **world_kwargs(world)).unwrapped
    assert face.world == world
    with pytest.raises(ValueError, match="the Gymnasium face shows one learner's view"):
        world_kwargs(world.replace(opponent="self"))


def test_a_checkpoint_written_before_the_one_layout_resumes(tmp_path):
    """A lone seed's checkpoint from da5af71 (its rows, best evaluation and replay buffer at the top level) resumes
    under today's one layout, and the run goes on to a longer budget."""
    import shutil

    from omegaconf import OmegaConf

    from sidewalk.config import validate
    from sidewalk.experiment import Trial
    from sidewalk.run_folder import CHECKPOINT, read_torch_file

    run = shutil.copytree(BEFORE_WORLD / "dqn_checkpoint", tmp_path / "run")
    old = read_torch_file(run / CHECKPOINT)
    assert "runs" not in old and isinstance(old["replay_buffer"], dict)  # the older lone layout
    cfg = OmegaConf.merge(OmegaConf.load(run / "config.yaml"), {"iterations": 3, "resume": True})
    (summary,) = Trial(validate(cfg), run, OmegaConf.to_container(cfg, resolve=True)).run(progress=False,
                                                                                        absolute_metric=False)
    assert summary["iterations"] == 3
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 3  # a header and three iterations
