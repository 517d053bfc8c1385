"""The human-proxy partner (opponent=proxy): behaviour cloning from a recorded dataset."""

from __future__ import annotations

import gymnasium
import pytest
import torch

pytest.importorskip("minari")
pytest.importorskip("h5py")

from torchrl.envs.utils import step_mdp

import sidewalk  # noqa: F401  # registers the Gymnasium ids
from sidewalk import datasets
from sidewalk.envs import ContinuousSidewalkEnv, DiscreteSidewalkEnv
from sidewalk.envs.base import AGENT_GROUP
from sidewalk.opponents.base import make_opponent
from sidewalk.partners.proxy import ProxyMismatch, ProxyOpponent, demonstrations

# The walker each domain records (as agent 0, the ego of the Gymnasium face) and the partner it walks against.
# Grid: the Dijkstra planner with its deterministic tie-break; continuous: a keep-right convention walker.
CASES = {
    "discrete": ("sidewalk/Discrete-v0", {"opponent": "dijkstra", "noise": 0.1, "max_steps": 60},
                 ("dijkstra", {"tie_break": "progress"}), 30),
    "continuous": ("sidewalk/Continuous-v0", {"opponent": "prm", "noise": 0.05, "max_steps": 80},
                   ("convention", {"style": "keep_right"}), 16),
}
CORES = {"discrete": DiscreteSidewalkEnv, "continuous": ContinuousSidewalkEnv}
# A continuous action matches when each of (acceleration, turn) is within 10 % of its range (±0.2 m/s², ±π/80 rad).
TOLERANCE_OF_RANGE = 0.1


def record(root, domain: str, name: str, seeds) -> None:
    env_id, env_config, (walker, walker_kwargs), _ = CASES[domain]
    env = datasets.record(gymnasium.make(env_id, **env_config), data_path=root)
    driver = datasets.ScriptedDriver(env, walker, **walker_kwargs)
    for seed in seeds:
        _, info = env.reset(seed=seed)
        driver.reset()
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(driver(info))
            done = terminated or truncated
    datasets.save(env, f"walks/{domain}-{name}-v0", env_config=env_config, data_path=root)


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp("datasets")
    for domain, (*_, episodes) in CASES.items():
        record(root, domain, "train", range(episodes))
        record(root, domain, "heldout", range(100, 106))
    return root


def matches(domain: str, predicted: torch.Tensor, actual: torch.Tensor, core) -> torch.Tensor:
    """Per step, whether the proxy's action matches the walker's (grid: the same move; continuous: see
    TOLERANCE_OF_RANGE)."""
    if domain == "discrete":
        return predicted == actual
    bounds = torch.tensor([core.params.max_accel_mps2, core.params.max_turn_rad])
    return ((predicted - actual).abs() <= TOLERANCE_OF_RANGE * 2 * bounds).all(-1)


def proxy_on(root, domain: str, **kwargs) -> ProxyOpponent:
    env_config = CASES[domain][1]
    core = CORES[domain](1, seed=0, noise=env_config["noise"], max_steps=env_config["max_steps"])
    return ProxyOpponent(core, controlled=(1,), ego=0, dataset=f"walks/{domain}-train-v0", data_path=str(root), **kwargs)


@pytest.mark.parametrize("domain", CASES)
def test_the_proxy_matches_the_walker_on_held_out_steps(root, domain):
    proxy = proxy_on(root, domain)
    observations, actions, _ = demonstrations(datasets.load(f"walks/{domain}-heldout-v0", data_path=root))
    with torch.no_grad():
        predicted = proxy.clone.act(observations)
    share = matches(domain, predicted, actions, proxy.env).float().mean().item()
    assert len(actions) >= 100
    assert share >= 0.9, f"the proxy matches the walker on {share:.0%} of {len(actions)} held-out steps"


def closed_loop(root, domain: str, agent: int, episodes: int = 4) -> tuple[float, int, int]:
    """The proxy plays ``agent`` against the recording's partner in the other role: the share of its steps on which
    it acts as the walker in its place would, its steps, and the episodes in which it reached its goal."""
    env_config, (walker, walker_kwargs) = CASES[domain][1], CASES[domain][2]
    core = CORES[domain](1, seed=0, noise=env_config["noise"], max_steps=env_config["max_steps"])
    proxy = ProxyOpponent(core, controlled=(agent,), ego=1 - agent, dataset=f"walks/{domain}-train-v0",
                          data_path=str(root))
    partner = make_opponent(env_config["opponent"], core, controlled=(1 - agent,), ego=agent)
    reference = make_opponent(walker, core, controlled=(agent,), ego=None, **walker_kwargs)
    agreed, reached = [], 0
    for seed in range(episodes):
        core.set_seed(seed)
        td = core.reset()
        for _ in range(core.params.max_steps):
            inputs = [td.get((AGENT_GROUP, key)) for key in ("state", "goal", "done")]
            wanted = reference.act(*inputs)[:, 0]
            td = partner(proxy(td))
            if not bool(inputs[2][0, agent]):  # the steps the proxy's agent walks
                agreed.append(matches(domain, td.get((AGENT_GROUP, "action"))[:, agent], wanted, core))
            td = step_mdp(core.step(td))
            if bool(td.get("done").any()):
                break
        reached += bool(td.get((AGENT_GROUP, "info", "reached_goal"))[0, agent])
    return torch.cat(agreed).float().mean().item(), len(agreed), reached


@pytest.mark.parametrize("domain", CASES)
def test_the_proxy_walks_as_the_walker_in_closed_loop(root, domain):
    """In the recorded role the proxy walks its own episodes step for step as the walker would; in the other role
    (its world turned by half a turn, the sidewalk's symmetry) it still walks to its goal."""
    share, steps, reached = closed_loop(root, domain, agent=0)
    assert share >= 0.9, f"the proxy matches the walker on {share:.0%} of its {steps} steps"
    assert reached >= 3
    _, _, reached_as_agent_1 = closed_loop(root, domain, agent=1)
    assert reached_as_agent_1 >= 3, f"as agent 1 the proxy reached its goal in {reached_as_agent_1} of 4 episodes"


def test_the_clone_is_cached_beside_the_dataset_and_reused(root, monkeypatch):
    first = proxy_on(root, "discrete", seed=3, epochs=20)
    weights = list((root / "walks" / "discrete-train-v0" / "proxy").glob("*.pt"))
    assert weights
    import sidewalk.partners.proxy as proxy_module

    def refuse(*args, **kwargs):
        raise AssertionError("trained again although its weights are cached")

    monkeypatch.setattr(proxy_module, "train_clone", refuse)
    again = proxy_on(root, "discrete", seed=3, epochs=20)
    for name, value in first.clone.state_dict().items():
        assert torch.equal(value, again.clone.state_dict()[name]), name


def test_a_dataset_of_another_world_is_refused(root):
    with pytest.raises(ProxyMismatch, match="continuous domain"):
        ProxyOpponent(DiscreteSidewalkEnv(1, seed=0), dataset="walks/continuous-train-v0", data_path=str(root))
    with pytest.raises(ProxyMismatch, match="observation='image'"):
        ProxyOpponent(DiscreteSidewalkEnv(1, seed=0, observation="vector"), dataset="walks/discrete-train-v0",
                      data_path=str(root))
    with pytest.raises(ProxyMismatch, match="opponent.params.dataset"):
        ProxyOpponent(DiscreteSidewalkEnv(1, seed=0))
    with pytest.raises(FileNotFoundError, match="walks/none-v0") as missing:
        ProxyOpponent(DiscreteSidewalkEnv(1, seed=0), dataset="walks/none-v0", data_path=str(root))
    # What is there, and where the proxy's root is set: the guide's recording is not under Minari's default.
    assert "datasets there: walks/continuous-heldout-v0, walks/continuous-train-v0," in str(missing.value)
    assert "opponent.params.data_path=DIR" in str(missing.value) and "MINARI_DATASETS_PATH=DIR" in str(missing.value)


def test_the_proxy_is_a_partner_of_the_gymnasium_face(root):
    env = gymnasium.make("sidewalk/Discrete-v0", opponent="proxy", noise=0.1,
                         opponent_kwargs={"dataset": "walks/discrete-train-v0", "data_path": str(root)})
    driver = datasets.ScriptedDriver(env, "dijkstra")  # the recording's partner, now as agent 0
    reached = 0
    for seed in range(3):
        _, info = env.reset(seed=seed)
        driver.reset()
        for _ in range(60):
            _, _, terminated, truncated, info = env.step(driver(info))
            if terminated or truncated:
                break
        reached += bool(info["agents"]["reached_goal"][1])
    assert reached >= 2, f"the proxy partner reached its goal in {reached} of 3 episodes"
