"""The shell commands of README.md and docs/: every command of every ```bash block runs as a user pastes it, with a
small budget, or is in ``NOT_RUN`` with the reason and the test that covers its code path.

A command is a line of a bash block (``\\`` continuations joined, ``#`` comments dropped), or one part of an ``&&``
chain. It runs with only keys a user could add appended, and never one the command sets itself: ``runners/main.py``
gets ``BUDGET`` (iterations, evaluation and the learner's batch; a run or sweep folder of the test's), another runner
its smallest sizes (``RUNNER_BUDGET``). Placeholders (``<RUN_DIR>``, ``results/sweeps/<sweep>``, ``RUN_OR_SWEEP...``)
are filled with folders an earlier command made (``FILL``), and a shell's globs are expanded as a shell does.

Every command runs in ONE interpreter (``BATCH``: ``runners/main.py``'s ``cli()`` by runpy, a runner's ``main(argv)``,
``python -m`` by runpy), in a temporary working folder, in page order; a command two pages share runs once. The batch
runs once per session (the first test that asks; under xdist the other workers wait and read its outcomes), and each
page's test checks its commands' exit status and, where cheap, what they wrote.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from test_docs import FENCE, ROOT, child_env, python_blocks, tail

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "docs" / "guide").glob("*.md"))]

# runners/main.py's budget: appended where the command does not set the key (a preset's iterations are not what it
# shows; `scale=quick`'s are a budget too). Smaller worlds and batches, short episodes, one evaluation at the end.
BUDGET = {"iterations": "2", "eval_every": "2", "eval_episodes": "4", "num_envs": "4", "algo.frames_per_batch": "16",
          "env.max_steps": "30", "checkpoint_every": "0", "logger": "none", "plots": "false"}
# A run's length is a budget even where the command gives one (`iterations=1000`): what it shows is something else.
BUDGET_OVER_THE_COMMAND = ("iterations", "eval_every")
# A preset's seeds are its budget, what it shows is its other axes: a sweep over seeds runs its first seed, and a
# preset's replicas one (`scale=quick`'s two seeds are what that command shows, and stay).
SEED_SWEEPS = ("+experiment=selfplay_discrete", "+experiment=selfplay_continuous", "+experiment=safe_discrete",
               "+experiment=teams_discrete")
# Another runner's smallest sizes, flags its --help lists (appended where the command does not give the flag).
RUNNER_BUDGET = {
    "crossplay.py": {"--episodes": "4", "--no-progress": None},
    "crossplay.py --train-best-responses": {"--iterations": "2", "--episodes": "4", "--no-progress": None,
                                            "--override": [f"{key}={value}" for key, value in BUDGET.items()
                                                           if key != "iterations"]},
    "report.py": {"--resamples": "100"},
    "render.py": {},
    "baselines.py": {"--seeds": "0", "--episodes": "1"},
    "partners.py": {},  # list and show print, export writes one small file: seconds
    "bench.py env": {},  # 4096 worlds is what it shows; the section has no flag for its timed seconds
    "bench.py": {"--num-envs": "8", "--threads": "1"},  # --seconds is a section's flag, after a section's name
    "bench.py scenarios": {"--agents": "2", "--seconds": "0.05", "--repeats": "1", "--num-envs": "8"},
}

# Placeholders and paths of an earlier step, filled with the folder an earlier command of this test made: a run's
# folder is runs/<page>-<n> (the n-th command of its page), a sweep's sweeps/<page>-<n>; * is a shell glob.
FILL = {
    "python runners/crossplay.py RUN_OR_SWEEP... --partners heldout --out results/adhoc":
        {"RUN_OR_SWEEP...": "runs/adhoc-1 runs/adhoc-2"},
    "python runners/crossplay.py SELFPLAY OTHERPLAY POPULATION --partners heldout --out "
    "results/reference/adhoc/continuous": {"SELFPLAY": "runs/adhoc-4", "OTHERPLAY": "runs/adhoc-5",
                                           "POPULATION": "runs/adhoc-6"},
    "python runners/main.py +experiment=selfplay_discrete algo=iql seed=S": {"seed=S": "seed=0"},
    "python runners/crossplay.py IQL_SELFPLAY --partners heldout --out results/reference/adhoc/discrete":
        {"IQL_SELFPLAY": "runs/adhoc-8"},
    "python runners/report.py 'results/sweeps/<sweep>' '[more' 'folders]' '[--out' 'DIR]'":
        {"'results/sweeps/<sweep>' '[more' 'folders]' '[--out' 'DIR]'": "sweeps/README-8 runs/README-2 --out report"},
    "python runners/render.py 'results/sweeps/<sweep>/<job>' --episode 0": {"'results/sweeps/<sweep>/<job>'":
                                                                            "sweeps/README-8/0_*"},
    "python runners/main.py opponent=policy 'opponent.path=results/runs/<RUN_DIR>'":
        {"'opponent.path=results/runs/<RUN_DIR>'": "opponent.path=runs/README-2"},
    "python runners/crossplay.py 'results/sweeps/<A>' 'results/sweeps/<B>' --out results/crossplay":
        {"'results/sweeps/<A>' 'results/sweeps/<B>'": "sweeps/multiagent-4 sweeps/experiments-5"},
    "python runners/report.py 'results/runs/<RUN_DIR>' --out results/who-yields-report":
        {"'results/runs/<RUN_DIR>'": "runs/multiagent-9"},
    "python -m sidewalk.reference collect results/sweeps/reference/seeds0-4 results/reference/runs/seeds0-4":
        {"results/sweeps/reference/seeds0-4": "sweeps/README-8"},
    "python runners/crossplay.py RUN_DIR --partners zoo:discrete/vdn_seed0,zoo:keep_left --out results/zoo-crossplay":
        {"RUN_DIR": "runs/partners-4"},
}
# A command that continues a run needs the run: trained first, at the same budget, in the folder it names (emptied
# first: two pages continue results/runs/mine, one a single run, one a group of five).
BEFORE = {
    "python runners/main.py hydra.run.dir=results/runs/mine resume=true": ["hydra.run.dir=results/runs/mine"],
    "python runners/main.py hydra.run.dir=results/runs/mine replicas=5 resume=true":
        ["hydra.run.dir=results/runs/mine", "replicas=5"],
}
# The page whose Python snippets make what its commands read (datasets.md records the dataset opponent=proxy plays).
SNIPPETS_FIRST = ("docs/guide/datasets.md",)

# Every command that does not run here: the reason, and the test that covers its code path.
NOT_RUN = {
    "pip install -e . -c constraints.txt":
        ("installs the package", "tests/test_packaging.py builds and installs it into a fresh venv"),
    "pip install -e '.[dev]' -c constraints.txt": ("installs the package", "tests/test_packaging.py"),
    "pip install --no-deps benchmarl==1.5.2": ("installs BenchMARL", "tests/test_benchmarl.py (skips without it)"),
    "pip install --no-deps benchmarl==1.5.2 id-marl-eval==0.0.4 colorama==0.4.6":
        ("installs BenchMARL and marl-eval", "tests/test_benchmarl.py, tests/test_marl_eval.py"),
    "python -m pytest": ("the suite itself", "this suite"),
    "python -m sphinx -b html docs build/docs":
        ("the site's build (a minute)", "tests/test_docs.py::test_the_site_builds_without_warnings_or_optional_packages"),
    "python runners/main.py -m seed=0,1,2 hydra/launcher=submitit_slurm hydra.launcher.partition=gpu":
        ("needs a Slurm cluster", "the same sweep runs above with the basic launcher and with joblib"),
    "runners/reproduce.sh '[full|quick]'":
        ("every preset's sweep: days (full) or dozens of jobs (quick)",
         "runners/reproduce.sh --list runs its plan here; tests/test_reproduce.py runs the pool"),
    "runners/reproduce.sh full --processes 2 replicas=5 --out results/sweeps/mine":
        ("every preset's sweep at the paper's budgets: days", "tests/test_reproduce.py (overrides, --processes, --out)"),
    "python -m sidewalk.reference check":
        ("the full reference check: a probe job per recorded reference (minutes)",
         "tests/test_reference.py runs the check job by job"),
    "python -m sidewalk.reference check --write-status":
        ("the full reference check, and it rewrites results/reference/freshness.md in the checkout",
         "tests/test_reference.py"),
    "python -m sidewalk.reference probe results/reference --tree ../ref":
        ("needs a checkout of the reference's commit in ../ref", "tests/test_reference.py"),
    "python runners/render.py --gallery docs/scenarios":
        ("renders every scenario of both domains, a still and a GIF each (15 CPU-s)",
         "tests/test_render_gallery.py renders each scenario; render.py's run and scripted forms run above"),
    "results/reference/safe/run.sh":
        ("the reference table's sweeps at their budgets (hours, 5 seeds a job, interpreters of their own)",
         "tests/test_safety.py; the same presets run above at a small budget"),
    "python runners/crossplay.py --train-best-responses continuous --out results/reference/adhoc/continuous":
        ("trains a best response to every held-out member", "tests/test_brprox.py; the discrete form runs above"),
    "python runners/bench.py training": ("~1 h, and Stable-Baselines3", "tests/test_training_bench.py"),
    "python runners/bench.py geometry": ("~6 min of episodes", "tests/test_continuous_geometry.py"),
    "python runners/bench.py budget --baseline f082f2a":
        ("~12 min, and a checkout of another revision", "tests/test_budget_bench.py"),
    "python runners/bench.py reproduce --baseline 681260b":
        ("~20 min, and a checkout of another revision", "tests/test_reproduce_bench.py"),
    "python runners/bench.py learners --learners ours-trpo sb3-contrib-trpo":
        ("hours of training, and sb3-contrib", "tests/test_bench_learners.py"),
    "python runners/bench.py learners --learners ours-ppo sb3-ppo --opponent prm":
        ("hours of training, and Stable-Baselines3", "tests/test_bench_learners.py"),
    "OMP_WAIT_POLICY=PASSIVE python runners/bench.py multiagent":
        ("~12 min at 4096 worlds, and VMAS", "tests/test_multiagent_bench.py"),
    **{command: ("needs BenchMARL (installed apart; not in the dev extras)", "tests/test_benchmarl.py")
       for command in [
           ("python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous "
           "'experiment.loggers=[csv]'"),
           ("python -m sidewalk.interop.benchmarl -m algorithm=iql,vdn,qmix task=sidewalk/sidewalk_discrete seed=0,1,2 "
           "'experiment.loggers=[csv]'"),
           "python -m sidewalk.interop.benchmarl algorithm=mappo task=sidewalk/door_continuous tuned=default",
           ("python runners/bench.py benchmarl --bm-config default --bm-tasks sidewalk_continuous door_continuous "
           "--bm-out results/benchmarl"),
           ("python runners/bench.py benchmarl --bm-config default --bm-tasks sidewalk_discrete door_discrete "
           "--bm-grid-observation vector --bm-out results/benchmarl"),
           ("python runners/bench.py benchmarl --bm-config default --bm-algorithms mappo --bm-tasks sidewalk_continuous "
           "--bm-no-state --bm-out results/benchmarl"),
           ("python runners/bench.py benchmarl --bm-algorithms mappo ippo --bm-tasks door_continuous "
           "--bm-out results/benchmarl"),
           ("python runners/bench.py benchmarl --bm-algorithms iql vdn qmix --bm-tasks sidewalk_discrete "
           "--bm-out results/benchmarl"),
       ]},
    **{command: ("a plug-in package the page writes, not one that ships", "tests/test_plugins.py builds and installs one")
       for command in [
           "pip install -e ./sidewalk-corridor",
           "sidewalk-train opponent=shy",
           "sidewalk-train env.layout=corridor env.width_cells=3 env.length_cells=9 env.observation=vector",
           "sidewalk-train algo=greedy_dqn",
           "sidewalk-train -m opponent=shy,random algo=greedy_dqn,dqn seed=0,1,2",
       ]},
    **{command: ("the browser page's server runs until stopped", "tests/test_play.py drives sidewalk-play in Chromium")
       for command in [
           "sidewalk-play",
           "sidewalk-play env=continuous opponent=prm",
           "sidewalk-play opponent=convention opponent.params.style=keep_right",
           "sidewalk-play env=continuous opponent=population",
           "sidewalk-play opponent=policy 'opponent.path=results/runs/<RUN_DIR>'",
           "sidewalk-play env=continuous opponent=proxy opponent.params.dataset=sidewalk-play/continuous-prm-v0",
           "sidewalk-play env.layout=door env.n_agents=3 opponent=dijkstra",
       ]},
}


def page_name(page: Path) -> str:
    return str(page.relative_to(ROOT))


def commands(page: Path) -> list[tuple[int, str]]:
    """The commands of ``page``'s bash blocks as (line, command), in page order: continuations joined, comments
    dropped, an ``&&`` chain split into its commands; a command is its words, quoted as a shell would need them."""
    text, found = page.read_text(), []
    for match in FENCE.finditer(text):
        if match["info"].split()[:1] != ["bash"]:
            continue
        first = text.count("\n", 0, match.start("body")) + 1
        lines = match["body"].splitlines()
        index = 0
        while index < len(lines):
            line, start = lines[index], index
            while line.endswith("\\") and index + 1 < len(lines):
                index += 1
                line = line[:-1] + " " + lines[index].strip()
            index += 1
            words = shlex.split(line, comments=True)
            part: list[str] = []
            for word in [*words, "&&"]:
                if word != "&&":
                    part.append(word)
                elif part:
                    found.append((first + start, shlex.join(part)))
                    part = []
    return found


def label(page: Path) -> str:
    return page.stem


def plan(workdir: Path) -> list[dict]:
    """Every runnable command as a step of ``BATCH``, in page order, a command two pages share once."""
    steps, seen = [], set()
    for page in PAGES:
        if page_name(page) in SNIPPETS_FIRST:
            steps.append({"kind": "snippets", "blocks": python_blocks(page), "command": f"{page_name(page)} snippets"})
        for number, (_, command) in enumerate(commands(page), start=1):
            if command in NOT_RUN or command in seen:
                continue
            seen.add(command)
            steps.extend(command_steps(command, f"{label(page)}-{number}"))
    return steps


def command_steps(command: str, name: str) -> list[dict]:
    """The steps that run ``command``: the budget appended, placeholders filled, a run it continues trained first."""
    text = command
    for placeholder, value in FILL.get(command, {}).items():
        assert placeholder in text, f"FILL names {placeholder!r}, which {command!r} does not hold"
        text = text.replace(placeholder, value)
    words = shlex.split(text)
    env = {}
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
        key, _, value = words.pop(0).partition("=")
        env[key] = value
    if words[:1] == ["python"] and words[1:2] == ["-m"]:
        return [{"kind": "module", "target": words[2], "argv": words[3:], "env": env, "command": command}]
    if words[:1] == ["python"] and words[1] == "runners/main.py":
        arguments = words[2:]
        steps = []
        if command in BEFORE:
            steps.append({"kind": "main", "argv": main_budget(BEFORE[command], name + "-before"), "env": env,
                          "command": f"(the run that {command!r} continues)",
                          "clear": BEFORE[command][0].split("=", 1)[1]})
        return [*steps, {"kind": "main", "argv": main_budget(arguments, name), "env": env, "command": command}]
    if words[:1] == ["python"] and words[1].startswith("runners/"):
        script = Path(words[1]).name
        arguments = words[2:]
        section = f"{script} {arguments[0]}" if arguments and not arguments[0].startswith("-") else script
        flavour = (f"{script} --train-best-responses" if "--train-best-responses" in arguments
                   else section if section in RUNNER_BUDGET else script)
        return [{"kind": "runner", "target": script[:-3], "argv": runner_budget(arguments, RUNNER_BUDGET[flavour]),
                 "env": env, "command": command}]
    if words[0].startswith("runners/"):
        return [{"kind": "shell", "argv": [str(ROOT / words[0]), *words[1:]], "env": env, "command": command}]
    raise AssertionError(f"no way to run {command!r}: add it to NOT_RUN with its reason, or teach command_steps")


def main_budget(arguments: list[str], name: str) -> list[str]:
    keys = {argument.split("=", 1)[0].lstrip("+") for argument in arguments if "=" in argument}
    sweep = "-m" in arguments or "--multirun" in arguments
    extra = [f"{key}={value}" for key, value in BUDGET.items() if key not in keys or key in BUDGET_OVER_THE_COMMAND]
    if sweep and any(argument in SEED_SWEEPS for argument in arguments) and "seed" not in keys:
        extra.append("seed=0")
    if "experiment" in keys and not {"replicas", "scale"} & keys:
        extra.append("replicas=1")
    if sweep and "hydra.sweep.dir" not in keys:
        extra.append(f"hydra.sweep.dir=sweeps/{name}")
    if not sweep and "hydra.run.dir" not in keys:
        extra.append(f"hydra.run.dir=runs/{name}")
    if "--help" in arguments:
        extra = []
    return [*arguments, *extra]


def runner_budget(arguments: list[str], budget: dict) -> list[str]:
    extra = []
    for flag, value in budget.items():
        if flag in arguments:
            continue
        values = value if isinstance(value, list) else [] if value is None else [value]
        extra += [flag] if value is None else [word for item in values for word in (flag, item)]
    return [*arguments, *extra]


# Runs the steps of argv[1] (JSON) in the working folder, one after the other, and writes each one's exit status, the
# tails of its output and its CPU seconds to argv[2]. Output is collected in files, not pipes: Hydra's log handlers
# and tqdm hold the streams they were given.
BATCH = r"""
import contextlib, glob, importlib.util, io, json, os, resource, runpy, shutil, subprocess, sys
root, steps, outcomes_file = sys.argv[3], json.load(open(sys.argv[1])), sys.argv[2]
sys.path.insert(0, root)
cli = runpy.run_path(os.path.join(root, "runners", "main.py"))["cli"]
runners = {}

def runner(name):
    if name not in runners:
        spec = importlib.util.spec_from_file_location(f"runner_{name}", os.path.join(root, "runners", name + ".py"))
        runners[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(runners[name])
    return runners[name]

def expand(words):  # a shell's globs
    return [match for word in words for match in (sorted(glob.glob(word)) if "*" in word else None) or [word]]

def cpu():
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

outcomes = []
for step in steps:
    os.environ.pop("HYDRA_FULL_ERROR", None)  # cli() sets it for Hydra; each command starts as from the shell
    saved_env = dict(os.environ)
    os.environ.update(step.get("env", {}))
    if step.get("clear"):
        shutil.rmtree(step["clear"], ignore_errors=True)
    out, err, start = io.StringIO(), io.StringIO(), cpu()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            if step["kind"] == "main":
                sys.argv = ["runners/main.py", *expand(step["argv"])]
                cli()
                status = 0
            elif step["kind"] == "runner":
                sys.argv = [f"runners/{step['target']}.py", *expand(step["argv"])]
                status = runner(step["target"]).main(sys.argv[1:]) or 0
            elif step["kind"] == "module":
                sys.argv = [step["target"], *expand(step["argv"])]
                runpy.run_module(step["target"], run_name="__main__", alter_sys=True)
                status = 0
            elif step["kind"] == "snippets":
                namespace = {"__name__": "__main__"}
                for page, line, code in step["blocks"]:
                    exec(compile("\n" * (line - 1) + code, page, "exec"), namespace)
                status = 0
            else:
                done = subprocess.run(expand(step["argv"]), capture_output=True, text=True, check=False)
                print(done.stdout)
                print(done.stderr, file=sys.stderr)
                status = done.returncode
        except SystemExit as stop:
            status = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
            if not isinstance(stop.code, (int, type(None))):
                print(stop.code, file=sys.stderr)
        except BaseException:
            import traceback
            traceback.print_exc()
            status = 1
    os.environ.clear()
    os.environ.update(saved_env)
    outcomes.append({"status": status, "stdout": out.getvalue()[-3000:], "stderr": err.getvalue()[-3000:],
                     "cpu_s": round(cpu() - start, 2)})
with open(outcomes_file, "w") as file:
    json.dump(outcomes, file)
"""


@pytest.fixture(scope="session")
def outcomes(tmp_path_factory) -> dict[str, dict]:
    """Each command's outcome (and the working folder), run once for the session: by whichever worker asks first."""
    worker_root = tmp_path_factory.getbasetemp()
    shared = worker_root.parent if os.environ.get("PYTEST_XDIST_WORKER") else worker_root
    workdir, done = shared / "docs-commands", shared / "docs-commands.json"
    with open(shared / "docs-commands.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            workdir.mkdir(exist_ok=True)
            steps = plan(workdir)
            (workdir / ".steps.json").write_text(json.dumps(steps))
            env = child_env()
            env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
            env.pop("HYDRA_FULL_ERROR", None)
            ran = subprocess.run([sys.executable, "-c", BATCH, str(workdir / ".steps.json"), str(done) + ".tmp",
                                  str(ROOT)], cwd=workdir, env=env, capture_output=True, text=True, timeout=900,
                                 check=False)
            assert ran.returncode == 0, tail(ran.stdout + ran.stderr)
            results = json.loads(Path(str(done) + ".tmp").read_text())
            done.write_text(json.dumps({"workdir": str(workdir), "steps": [
                {**step, **result} for step, result in zip(steps, results, strict=True)]}))
    return json.loads(done.read_text())


@pytest.mark.parametrize("page", [page for page in PAGES if commands(page)], ids=page_name)
def test_the_commands_of_a_page_run(page: Path, outcomes) -> None:
    ran = {}
    for step in outcomes["steps"]:
        ran.setdefault(step["command"], []).append(step)
    failures = []
    for line, command in commands(page):
        if command in NOT_RUN:
            continue
        assert command in ran, f"{page_name(page)}:{line}: {command!r} neither ran nor is in NOT_RUN"
        for step in ran[command]:
            if step["status"] != 0:
                failures.append(f"{page_name(page)}:{line}: {command}\n  ran as {step['kind']} {step.get('argv')}\n"
                                f"  exit {step['status']}\n{step['stdout'][-1500:]}\n{step['stderr'][-1500:]}")
    assert not failures, "\n\n".join(failures)


def test_every_command_runs_or_is_listed_with_its_reason() -> None:
    shown = {command for page in PAGES for _, command in commands(page)}
    stale = sorted(set(NOT_RUN) - shown)
    assert not stale, f"NOT_RUN names commands no page shows: {stale}"
    for table in (FILL, BEFORE):
        stale = sorted(set(table) - shown)
        assert not stale, f"a command no page shows: {stale}"
    for command in shown - set(NOT_RUN):
        command_steps(command, "check")  # a command the test cannot run fails here, naming itself


def test_ci_runs_the_readme_s_test_command_as_the_pages_show_it() -> None:
    """.ci/run's last line is the README's second command, and the site's front page shows the same (before its
    comment): an install the tests need (BenchMARL, marl-eval) is in all three or in none."""
    readme = FENCE.search((ROOT / "README.md").read_text())["body"].splitlines()[1]
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    index = next(line for line in (ROOT / "docs" / "index.md").read_text().splitlines() if "python -m pytest" in line)
    assert ci == readme
    assert shlex.split(index, comments=True) == shlex.split(readme)


def test_the_commands_wrote_what_they_promise(outcomes) -> None:
    workdir = Path(outcomes["workdir"])
    for run in ("README-2", "README-6", "evaluation-2", "multiagent-5"):
        assert (workdir / "runs" / run / "summary.json").is_file(), run
    assert (workdir / "report").is_dir()
    assert (workdir / "results" / "crossplay").is_dir()
    assert (workdir / "results" / "adhoc").is_dir()

