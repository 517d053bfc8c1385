"""sidewalk-play in a real browser: Playwright drives Debian's Chromium (headless) through the page by keystrokes,
as a person would, against the package's env on the server; every played episode lands in a Minari dataset.

No person plays here: the keys come from a small scripted driver that reads the true state on the server and
presses what a person aiming for the goal would press.
"""

import base64
import io
import json
import math
import os
import re
import shutil
import socket
import urllib.error
import urllib.request

import minari
import numpy as np
import pytest
from matplotlib.image import imread

from sidewalk.config import opponent_domains
from sidewalk.envs.render import WALL, colour, draw_grid, draw_plane
from sidewalk.play import build_server
from sidewalk.play.command import compose_game_world

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium on this machine: apt-get install chromium (Debian's package)"
)
# Root runs Chromium without its sandbox; a closed network refuses Chromium's background connections.
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]


@pytest.fixture
def serve(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    servers = []

    def start(*overrides: str, **options):
        server = build_server(list(overrides), port=0, datasets=tmp_path / "datasets", **options)
        server.start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        pytest.skip("no Chromium on this machine: apt-get install chromium (Debian's package)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        chromium = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


def grid_move(info) -> str:
    row, col = info["state"][0]
    goal_row, goal_col = info["goal"][0]
    if col != goal_col:
        return "ArrowRight" if goal_col > col else "ArrowLeft"
    return "ArrowDown" if goal_row > row else "ArrowUp"


def continuous_keys(info) -> set[str]:
    x, y, speed, heading = info["state"][0]
    goal_x, goal_y = info["goal"][0]
    off = (math.atan2(goal_y - y, goal_x - x) - heading + math.pi) % (2 * math.pi) - math.pi
    keys = {"ArrowUp"} if speed < 0.6 else set()
    if abs(off) > 0.1:
        keys.add("ArrowLeft" if off > 0 else "ArrowRight")
    return keys


def play(page, server, press) -> int:
    """Keys until the page shows the episode over; returns the steps played."""
    steps = 0
    while page.get_attribute("#status", "data-done") != "true":
        assert steps < server.game.face.view.core.params.max_steps + 1
        press(server.game.info, steps)
        page.wait_for_function(f"Number(document.getElementById('step').textContent) > {steps}", timeout=10_000)
        steps = int(page.inner_text("#step"))
    return steps


def opened(browser, server, before=None):
    """A new page on ``server``, once it shows the world's first frame; ``before(page)`` runs before it loads."""
    page = browser.new_page()
    if before is not None:
        before(page)
    page.goto(server.url)
    page.wait_for_selector("#frame[src^='data:image/png']")
    return page


@needs_chromium
def test_a_grid_episode_played_by_keys_reaches_the_goal_and_is_recorded(serve, browser):
    server = serve("opponent=dijkstra")
    page = opened(browser, server)
    assert "against dijkstra" in page.inner_text("#about")
    steps = play(page, server, lambda info, _: page.keyboard.press(grid_move(info)))
    assert page.inner_text("#outcome") == "reached the goal"
    dataset = minari.load_dataset("sidewalk-play/discrete-dijkstra-v0")
    assert dataset.total_episodes == 1 and dataset.total_steps == steps
    episode = next(dataset.iterate_episodes())
    assert len(episode.actions) == steps and bool(episode.infos["is_success"][-1])
    page.close()


@needs_chromium
def test_a_continuous_episode_played_by_held_keys_reaches_the_goal_and_is_recorded(serve, browser):
    server = serve("env=continuous", "opponent=prm")
    page = opened(browser, server)
    held: set[str] = set()

    def press(info, steps):
        if steps == 8 and os.environ.get("SIDEWALK_PLAY_SCREENSHOT"):  # the guide's picture: docs/guide/play.md
            page.screenshot(path=os.environ["SIDEWALK_PLAY_SCREENSHOT"])
        wanted = continuous_keys(info)
        for key in held - wanted:
            page.keyboard.up(key)
        for key in wanted - held:
            page.keyboard.down(key)
        held.clear()
        held.update(wanted)

    steps = play(page, server, press)
    assert page.inner_text("#outcome") == "reached the goal"
    dataset = minari.load_dataset("sidewalk-play/continuous-prm-v0")
    assert dataset.total_episodes == 1 and dataset.total_steps == steps
    page.close()


@needs_chromium
def test_pause_holds_the_game_restart_starts_the_next_world_and_a_held_arrow_walks_on(serve, browser):
    server = serve("opponent=dijkstra", record=False)
    page = opened(browser, server)
    page.click("#pause")  # Start
    page.keyboard.press(" ")
    assert page.get_attribute("#status", "data-paused") == "true" and page.inner_text("#pause") == "Resume (space)"
    page.keyboard.press("ArrowRight")
    page.wait_for_timeout(600)  # more than two steps at the grid's four a second
    assert page.inner_text("#step") == "0"
    page.keyboard.press(" ")
    assert page.inner_text("#pause") == "Pause (space)" and page.inner_text("#status") == "playing"
    page.wait_for_function("document.getElementById('step').textContent === '1'", timeout=5_000)
    page.keyboard.press("r")
    page.wait_for_function("document.getElementById('episode').textContent === '2'", timeout=5_000)
    assert page.inner_text("#step") == "0"
    page.keyboard.down("ArrowRight")  # a held arrow walks on, one cell a step
    page.wait_for_function("Number(document.getElementById('step').textContent) >= 3", timeout=10_000)
    page.keyboard.up("ArrowRight")
    assert page.inner_text("#outcome") == "running" and server.game.info["state"][0][1] >= 3
    page.close()


def frame_of(page) -> np.ndarray:
    """The frame the page shows, as the RGB array the server's env drew."""
    png = base64.b64decode(page.get_attribute("#frame", "src").split(",", 1)[1])
    return (imread(io.BytesIO(png), format="png")[..., :3] * 255).round().astype(np.uint8)


def grid_cell(frame: np.ndarray, rows: int, cell) -> np.ndarray:
    k = frame.shape[0] // rows
    row, col = (int(value) for value in cell)
    return frame[row * k : (row + 1) * k, col * k : (col + 1) * k]


def pixels_of(patch: np.ndarray, rgb) -> int:
    return int((patch == np.array(rgb, dtype=np.uint8)).all(-1).sum())


@needs_chromium
def test_the_page_loads_without_an_error_and_the_world_waits_for_the_person_to_start(serve, browser):
    server = serve("env=continuous", "opponent=prm", record=False)
    failures = []

    def watch(page) -> None:
        page.on("response", lambda reply: reply.status >= 400 and failures.append(f"{reply.status} {reply.url}"))
        page.on("console", lambda message: message.type == "error" and failures.append(message.text))

    page = opened(browser, server, before=watch)
    page.wait_for_timeout(1500)  # seven steps of the world's five a second
    assert server.game.steps == 0 and page.inner_text("#step") == "0"
    assert "to begin" in page.inner_text("#status") and page.inner_text("#pause") == "Start"
    page.keyboard.down("ArrowUp")
    page.wait_for_function("Number(document.getElementById('step').textContent) >= 2", timeout=5_000)
    page.keyboard.up("ArrowUp")
    assert page.inner_text("#status") == "playing" and failures == []  # no /favicon.ico asked for, nor a 404
    page.close()


@needs_chromium
def test_your_goal_shows_under_the_partner_at_the_start(serve, browser):
    server = serve("opponent=dijkstra", record=False)
    page = opened(browser, server)
    info, rows = server.game.info, server.game.face.view.core.rows
    assert (info["state"][1] == info["goal"][0]).all()  # the partner starts on your goal
    goal = grid_cell(frame_of(page), rows, info["goal"][0])
    assert pixels_of(goal, colour(1)) >= 50  # the partner, and over its edge your star's outline: more than the
    assert pixels_of(goal, colour(0)) >= 100  # tips around it (30 px), which were all a person saw of the star
    page.close()


@needs_chromium
def test_after_a_crash_the_agent_shows_crossed_out_and_space_keeps_the_outcome(serve, browser):
    server = serve("opponent=dijkstra", record=False)
    page = opened(browser, server)
    play(page, server, lambda info, _: page.keyboard.press("ArrowUp"))  # up the grid, into its wall
    assert page.inner_text("#outcome") == "hit a wall"
    ego = grid_cell(frame_of(page), server.game.face.view.core.rows, server.game.info["state"][0])
    k = ego.shape[0]
    assert pixels_of(ego, colour(0)) >= 50 and tuple(ego[k // 2, k // 2]) == WALL  # drawn where it crashed, crossed
    page.keyboard.press(" ")
    assert page.inner_text("#status") == "episode over: hit a wall; R restarts"
    assert page.get_attribute("#status", "data-paused") == "false" and page.is_disabled("#pause")
    page.close()


def test_agents_that_collide_both_show_where_they_crashed():
    both = np.array([False, False])
    grid = draw_grid(3, 4, np.zeros((3, 4), bool), np.array([[1, 1], [1, 1]]), np.array([[0, 3], [2, 0]]), both, 24)
    plane = draw_plane(4.0, 2.0, np.zeros((0, 4)), np.array([[1.7, 1.0], [2.3, 1.0]]), np.zeros(2),
                       np.array([[3.5, 1.0], [0.5, 1.0]]), both, 0.3, 60)
    cell = grid_cell(grid, 3, (1, 1))  # one cell, shared by both
    assert pixels_of(cell, colour(0)) >= 30 and pixels_of(cell, colour(1)) >= 30 and tuple(cell[12, 12]) == WALL
    for agent, x_px in enumerate((4 + 1.7 * 60, 4 + 2.3 * 60)):  # 4 px of wall, 60 px a metre; y = 1 m: 64 px
        disc = plane[64 - 18 : 64 + 18, round(x_px) - 18 : round(x_px) + 18]
        assert pixels_of(disc, colour(agent)) >= 300 and tuple(disc[18, 18]) == WALL


def request(server, path: str, body: bytes | None = None, headers: dict[str, str] | None = None):
    headers = {"Content-Type": "application/json", **(headers or {})} if body is not None else headers or {}
    try:
        with urllib.request.urlopen(urllib.request.Request(server.url.rstrip("/") + path, data=body,
                                                           headers=headers)) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


@pytest.mark.parametrize("body, words", [
    (b"not json", "not JSON"),
    (b'{"move": "jump"}', "move='jump' is not valid; valid: up, down, left, right"),
    (b'[1, 2]', "is a JSON object"),
])
def test_a_malformed_message_is_a_400_naming_it_and_the_server_goes_on(serve, body, words):
    server = serve("opponent=dijkstra", record=False)
    status, reply = request(server, "/api/step", body)
    assert status == 400 and words in json.loads(reply)["error"]
    status, reply = request(server, "/api/step", b'{"move": "right"}')
    assert status == 200 and json.loads(reply)["step"] == 1


def test_a_message_that_does_not_say_it_is_json_is_a_400(serve):
    server = serve("opponent=dijkstra", record=False)
    status, reply = request(server, "/api/step", b'{"move": "right"}', {"Content-Type": "text/plain"})
    assert status == 400 and json.loads(reply)["error"] == ("a message of Content-Type 'text/plain' is not valid; "
                                                            "valid: application/json")
    assert server.game.steps == 0


def test_a_request_naming_another_host_is_refused(serve):
    server = serve("opponent=dijkstra", record=False)
    for path, body in (("/", None), ("/api/state", None), ("/api/step", b'{"move": "right"}')):
        status, reply = request(server, path, body, {"Host": f"rebound.example:{server.server_address[1]}"})
        assert status == 403 and "'rebound.example:" in json.loads(reply)["error"]
    assert server.game.steps == 0
    status, _ = request(server, "/", headers={"Host": f"localhost:{server.server_address[1]}"})
    assert status == 200


def test_an_episode_cut_by_a_restart_or_the_servers_end_is_saved_truncated(serve, tmp_path):
    server = serve("opponent=dijkstra", dataset_id="mine/cut-v0")
    for _ in range(3):
        request(server, "/api/step", b'{"move": "right"}')
    request(server, "/api/reset", b"{}")
    request(server, "/api/reset", b"{}")  # nothing played since: nothing saved
    for _ in range(2):
        request(server, "/api/step", b'{"move": "up"}')
    server.shutdown()
    server.server_close()
    dataset = minari.load_dataset("mine/cut-v0")
    episodes = list(dataset.iterate_episodes())
    assert [len(episode.actions) for episode in episodes] == [3, 2]
    assert all(episode.truncations[-1] and not episode.terminations.any() for episode in episodes)
    assert list(episodes[1].actions) == [0, 0]  # up, up


def test_the_episodes_played_here_make_a_proxy_partner_to_play_against(serve, tmp_path):
    recorder = serve("opponent=dijkstra", dataset_id="mine/walks-v0")
    for _ in range(6):
        request(recorder, "/api/step", b'{"move": "right"}')
    recorder.server_close()
    server = serve("opponent=proxy", "opponent.params.dataset=mine/walks-v0",
                   f"opponent.params.data_path={tmp_path / 'datasets'}", "opponent.params.epochs=20", record=False)
    start = server.game.info["state"][1].copy()
    status, reply = request(server, "/api/step", b'{"move": "up"}')
    assert status == 200 and json.loads(reply)["step"] == 1
    assert server.game.describe()["partner"] == "proxy" and (server.game.info["state"][1] != start).any()


def test_a_continuous_message_takes_only_minus_one_zero_or_one(serve):
    server = serve("env=continuous", "opponent=prm", record=False)
    status, reply = request(server, "/api/step", b'{"accelerate": 5, "turn": 0}')
    assert status == 400 and json.loads(reply)["error"] == "accelerate=5 is not valid; valid: -1, 0, 1"


@pytest.mark.parametrize("path", ["/../pyproject.toml", "/static/play.js", "/etc/passwd", "/api/../../x", "/play.py"])
def test_only_the_page_and_its_assets_are_served(serve, path):
    server = serve("opponent=dijkstra", record=False)
    assert request(server, path)[0] == 404
    for asset in ("/", "/play.js", "/play.css"):
        assert request(server, asset)[0] == 200


def test_it_listens_on_this_machine_only_unless_told(serve):
    assert serve("opponent=dijkstra", record=False).server_address[0] == "127.0.0.1"


def run_play(runner, *argv):
    return runner("play").main(list(argv))


@pytest.mark.parametrize("argv, words", [
    (["opponent=nobody", "--no-browser"], "opponent"),
    (["opponent=self", "--no-browser"], "opponent='self' is a learner's view, not a partner"),
    (["env=continuous", "opponent=dijkstra", "--no-browser", "--no-record"], "dijkstra"),
    (["noise=-1", "--no-browser", "--no-record"], "noise"),
    (["nosie=0.3", "--no-browser", "--no-record"], ("unknown key 'nosie' (did you mean 'noise'?) for the experiment "
                                                     "(top level); valid: env, opponent,")),
    (["noise=abc", "--no-browser", "--no-record"], "noise=abc: Value 'abc' of type 'str' could not be converted"),
    (["--dataset-id", "no-version", "--no-browser"], "is not of Minari's form"),
])
def test_bad_input_is_one_error_line_before_serving(runner, capsys, tmp_path, argv, words):
    assert run_play(runner, *argv, "--datasets", str(tmp_path)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and words in err[0], err


@pytest.mark.parametrize("domain, opponent", [("continuous", "dijkstra"), ("discrete", "self"), ("discrete", "nobody")])
def test_the_partners_named_valid_are_exactly_those_play_takes_in_that_world(runner, capsys, domain, opponent):
    assert run_play(runner, f"env={domain}", f"opponent={opponent}", "--no-browser", "--no-record") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and opponent in err[0], err
    named = re.search(r"valid[^:]*: (.*)$", err[0]).group(1).split(", ")
    for choice in opponent_domains():
        if choice in named:
            compose_game_world([f"env={domain}", f"opponent={choice}"])
        else:
            with pytest.raises(ValueError, match=f"opponent={choice!r} is"):
                compose_game_world([f"env={domain}", f"opponent={choice}"])


# test_experiment.py's tiny grid DQN run: finished_run trains it once for the whole suite.
TINY_GRID_RUN = ["num_envs=4", "iterations=12", "eval_every=4", "eval_episodes=8", "checkpoint_every=4", "logger=none",
                 "plots=false", "algo.frames_per_batch=16", "algo.batch_size=16", "algo.buffer_size=2000",
                 "algo.learning_starts=0", "algo.updates_per_batch=1"]


def test_a_run_folders_policy_is_a_partner_of_its_own_domain_only(finished_run, serve, runner, capsys, tmp_path):
    run = finished_run(TINY_GRID_RUN)
    server = serve("opponent=policy", f"opponent.path={run}", record=False)
    assert server.game.describe()["partner"] == "policy" and server.game.step({"move": "right"})["step"] == 1
    assert run_play(runner, "env=continuous", "opponent=policy", f"opponent.path={run}", "--no-browser",
                    "--no-record") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "trained in the discrete domain" in err[0], err


def test_a_port_in_use_is_one_error_line(runner, capsys, tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert run_play(runner, "--port", str(port), "--no-browser", "--no-record") == 2
    assert capsys.readouterr().err.strip() == (f"error: [Errno 98] port {port} on 127.0.0.1 is in use; pick another "
                                                "with --port (0: any free one)")


def test_a_dataset_of_another_world_is_refused_before_serving(serve, runner, capsys, tmp_path):
    server = serve("opponent=dijkstra", dataset_id="mine/walks-v0")
    while not server.game.step({"move": "right"})["done"]:
        pass
    assert run_play(runner, "opponent=dijkstra", "noise=0.2", "--dataset-id", "mine/walks-v0",
                    "--datasets", str(tmp_path / "datasets"), "--no-browser") == 2
    err = capsys.readouterr().err
    assert "was recorded under another env" in err and "noise" in err
