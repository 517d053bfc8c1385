"""The zoo's cards (``sidewalk-partners list`` and ``show``): what each partner is, how it was made, where it belongs
and every score recorded with it, written as a Hugging Face model card (YAML front matter with license, tags and
the scores as ``model-index`` results, then markdown). Every fact is read from where it is kept
(``sidewalk.partners.zoo``); a kind of score nothing recorded is said to be not measured."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sidewalk.interop.gymnasium import ENV_IDS
from sidewalk.partners.policy import Partner, read_partner
from sidewalk.partners.zoo import (
    FACTS_FILE,
    NOT_MEASURED,
    ZooPartner,
    facts,
    gymnasium_kwargs,
    license_id,
    partner,
    partners,
)
from sidewalk.registry import OPPONENTS

DOMAIN_WORDS = {"discrete": "grid", "continuous": "continuous (unicycle)"}
SPLIT_WORDS = {"training": "training (`opponent=population` draws it)",
               "heldout": "held out (`--partners heldout`: no learner meets it in training)"}
WITH = ("itself", "the scripted partners", "learners")  # whom a card's scores are with, each said or not measured
TEAM_SUCCESS = ("Team success: the share of episodes in which every agent reached its goal; one value a seed, the other "
                "side's (a learner's runs) or the evaluation's (with itself).")
SCORES_HEADER = ("| with | domain | noise | team success | seeds | episodes | source |",
                 "| --- | --- | --- | --- | --- | --- | --- |")


def scored_with(score: Mapping[str, Any]) -> str:
    """Whom a recorded score is with (``WITH``): itself, or learners (no score with a scripted one is recorded)."""
    return "itself" if score["with"] == "itself" else "learners"


def mean(values: Sequence[float]) -> float:
    return sum(values) / len(values)


def saved(entry: ZooPartner) -> Partner | None:
    """What a learned partner's ``policy.pt`` says of it (None for a scripted one)."""
    return read_partner(entry.folder) if entry.learned else None


def describe(entry: ZooPartner, policy: Partner | None) -> str:
    """What the partner is, in one sentence: its learner, seed and world, or its scripted opponent and settings."""
    if policy is not None:
        label = policy.label.replace(policy.algo_name, policy.algo_name.upper(), 1)  # "VDN self-play"
        observation = getattr(policy.world.env_params, "observation", None)
        seen = f" on {observation} observations" if observation else ""
        return (f"{label}, seed {entry.facts['trained']['seed']}, in the {DOMAIN_WORDS[policy.world.domain]} "
                f"sidewalk{seen}")
    settings = ", ".join(f"{key}={value}" for key, value in entry.member.params.items())
    doc = " ".join((OPPONENTS[entry.member.opponent].__doc__ or "").split()).replace("``", "`").split(". ")[0]
    return f"scripted `{entry.member.opponent}`" + (f" ({settings})" if settings else "") + f": {doc[:1].lower()}{doc[1:]}"


def split_text(entry: ZooPartner) -> str:
    """The split that holds it (``none``: no population does), per domain where they differ."""
    found = [entry.splits.get(domain, "none") for domain in entry.domains]
    if len(set(found)) == 1:
        return found[0]
    return ", ".join(f"{split} ({domain})" for domain, split in zip(entry.domains, found))


def list_line(entry: ZooPartner) -> str:
    """``sidewalk-partners list``'s line: name, kind, domains, split, team success with itself."""
    policy = saved(entry)
    kind = f"learned {policy.label}" if policy else f"scripted {entry.member.opponent}"
    itself = {}
    for domain in entry.domains:
        first = next((score for score in entry.scores(domain) if scored_with(score) == "itself"), None)
        itself[domain] = NOT_MEASURED if first is None else f"{mean(first['team_success']):.3f}"
    shown = (next(iter(itself.values())) if len(set(itself.values())) == 1
             else ", ".join(f"{value} ({domain})" for domain, value in itself.items()))
    return (f"{entry.name:24s} {kind:26s} {', '.join(entry.domains):21s} {split_text(entry):9s} "
            f"team success with itself: {shown}")


def front_matter(entry: ZooPartner, policy: Partner | None) -> dict[str, Any]:
    """The card's YAML header as the Hugging Face Hub reads a model card's: license, tags, and the recorded scores
    as ``model-index`` results (team success, not verified by the Hub)."""
    tags = ["sidewalk-problem", "reinforcement-learning", "multi-agent-reinforcement-learning", "ad-hoc-teamwork"]
    if policy is not None:
        tags += ["learned-partner", policy.algo_name, "self-play", "torchrl"]
    else:
        tags += ["scripted-partner", entry.member.opponent]
    tags += [DOMAIN_WORDS[domain].split()[0] for domain in entry.domains]
    header: dict[str, Any] = {"license": license_id(), "tags": tags}
    if policy is not None:
        header["library_name"] = "pytorch"
    results = [{"task": {"type": "reinforcement-learning", "name": "ad-hoc teamwork"},
                "dataset": {"type": ENV_IDS[score["domain"]], "name": f"the {DOMAIN_WORDS[score['domain']]} sidewalk"},
                "metrics": [{"type": "team_success", "name": f"team success with {score['with']}",
                             "value": round(mean(score["team_success"]), 4), "verified": False}]}
               for score in entry.scores()]
    if results:
        header["model-index"] = [{"name": entry.name, "results": results}]
    return header


def card(name: str) -> str:
    """The zoo partner ``name``'s card: YAML front matter, then what it is, how it was made, its scores, its use."""
    import yaml

    entry = partner(name)
    policy = saved(entry)
    header = yaml.safe_dump(front_matter(entry, policy), sort_keys=False, width=10**6).rstrip()
    lines = ["---", header, "---", "", f"# {entry.name}", "",
             f"A partner of the Sidewalk Problem's zoo: {describe(entry, policy)}.", "",
             "| | |", "| --- | --- |", f"| domains | {', '.join(entry.domains)} |",
             *(f"| split ({domain}) | {SPLIT_WORDS.get(entry.splits.get(domain), 'in no population')} |"
               for domain in entry.domains),
             *made_rows(entry),
             "", "## Scores", "",
             TEAM_SUCCESS, "", *SCORES_HEADER]
    for kind in WITH:
        scores = [score for score in entry.scores() if scored_with(score) == kind]
        unmeasured = f"| {kind} | {', '.join(entry.domains)} | | {NOT_MEASURED} | | | |"
        lines += [score_row(score) for score in scores] or [unmeasured]
    lines += ["", "## Use", "", "```bash", *use_commands(entry), "```"]
    if policy is not None:
        keywords = ", ".join(f"{key}={value!r}" for key, value in gymnasium_kwargs(policy.world, 1).items())
        lines += ["", (f"The ONNX file's input `observation` (batch, ...) is what `gymnasium.make("
                       f"{ENV_IDS[policy.world.domain]!r}, {keywords})` returns for agent 1 (`--agent` picks another); "
                       "its output `action` is what that env's `step` takes. The file's metadata names the partner and "
                       "these keywords.")]
    return "\n".join(lines) + "\n"


def made_rows(entry: ZooPartner) -> list[str]:
    """How it was made, as rows of the card's first table: a learned one's command, commit, wall clock and weights."""
    if not entry.learned:
        module = OPPONENTS[entry.member.opponent].__module__.replace(".", "/")
        return [f"| made by | hand: `{module}.py`, not trained |"]
    trained = entry.facts["trained"]
    command = f"`{trained['command']}`"
    if "replicas=" in trained["command"]:
        command += f" (this partner is its run of seed {trained['seed']}: `replicas` trains seeds in one process)"
    size_kb = (entry.folder / "policy.pt").stat().st_size // 1000
    return [f"| command | {command} |", f"| commit | {trained['commit']} |",
            *([f"| wall clock | {trained['wall_clock']} |"] if "wall_clock" in trained else []),
            f"| weights | `sidewalk/partners/{entry.name}/policy.pt` ({size_kb} KB, read as weights only) |"]


def score_row(score: Mapping[str, Any]) -> str:
    """One recorded score as a row of the card's scores table."""
    values = score["team_success"]
    shown = ", ".join(f"{value:.3f}" for value in values) + (f" (mean {mean(values):.3f})" if len(values) > 1 else "")
    episodes = f"{score['episodes']}" + (" each" if len(values) > 1 else "")
    if score.get("distinct_episodes"):
        episodes += f" ({', '.join(map(str, score['distinct_episodes']))} distinct)"
    return (f"| {score['with']} | {score['domain']} | {score['noise']:g} | {shown} | "
            f"{', '.join(map(str, score['seeds']))} | {episodes} | `{score['source']}` |")


def use_commands(entry: ZooPartner) -> list[str]:
    """The commands that play the partner: training, cross-play, the play page, and a learned one's export."""
    world = "" if entry.domains[0] == "discrete" else "env=continuous "
    chosen = f"opponent=zoo opponent.params.name={entry.name}"
    lines = [f"python runners/main.py {world}{chosen}   # train a learner with it",
             f"python runners/crossplay.py RUN_DIR --partners zoo:{entry.name} --out DIR   # cross-play",
             f"sidewalk-play {world}{chosen}   # walk against it"]
    if entry.learned:
        lines.append(f"sidewalk-partners export {entry.name} --format onnx --out {entry.name.split('/')[-1]}.onnx")
    return lines


# ---- where the scores come from ----------------------------------------------------------------------------------

README_SOURCE = "sidewalk/partners/README.md"  # the learned partners' scores with themselves: their runs' last evaluations


def recorded_scores(reference: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Every score a clone's reference results (``reference``: its ``results/reference``) record with a zoo partner,
    by partner, as ``zoo.yaml`` keeps them: the held-out partners' cross-play cells with each learner condition
    (``adhoc/<domain>/crossplay.csv``) and their best responses (``best_responses.csv``), and the scripted baselines'
    random team, two uniform-random agents (``scenarios/baselines.csv``)."""
    import pandas as pd

    reference, scores = Path(reference), {}
    for folder in sorted(path.parent for path in (reference / "adhoc").glob("*/crossplay.csv")):
        meta = json.loads((folder / "crossplay.json").read_text())
        domain, source = meta["domain"], f"results/reference/adhoc/{folder.name}"
        cells = pd.read_csv(folder / "crossplay.csv")
        for label, partner_cells in cells[cells["heldout"]].groupby("partner_label", sort=False):
            name = f"{domain}/{label}" if partner_cells["partner_kind"].iloc[0] == "learned" else label
            for row_label, rows in partner_cells.groupby("row_label", sort=False):
                rows = rows.sort_values("row_seed")
                scores.setdefault(name, []).append({
                    "with": row_label, "domain": domain, "noise": float(meta["noise"]),
                    "seeds": rows["row_seed"].tolist(), "team_success": rows["team_success"].tolist(),
                    "episodes": int(rows["episodes"].max()), "distinct_episodes": rows["distinct_episodes"].tolist(),
                    "source": f"{source}/crossplay.csv"})
        for response in pd.read_csv(folder / "best_responses.csv").to_dict("records"):
            algo = re.search(r"\balgo=(\S+)", response["command"])[1]
            seed = int(re.search(r"\bseed=(\d+)", response["command"])[1])
            learned = f"{domain}/{response['member']}"
            scores.setdefault(learned if learned in partners() else response["member"], []).append({
                "with": f"its best response ({algo}, {response['budget']} iterations against it alone)",
                "domain": domain, "noise": float(meta["noise"]), "seeds": [seed],
                "team_success": [float(response["success"])], "episodes": int(response["episodes"]),
                "distinct_episodes": [int(response["distinct_low"])], "source": f"{source}/best_responses.csv"})
    baselines = pd.read_csv(reference / "scenarios" / "baselines.csv")
    made = (reference / "scenarios" / "baselines.md").read_text()
    episodes = int(re.search(r"(\d+) seeds × (\d+) episodes", made)[2])
    random_team = baselines[(baselines["scenario"] == "sidewalk") & (baselines["team"] == "random")]
    for (domain, noise), rows in random_team.groupby(["domain", "noise"], sort=False):
        rows = rows.sort_values("seed")
        scores.setdefault("random", []).append({
            "with": "itself", "domain": domain, "noise": float(noise), "seeds": rows["seed"].tolist(),
            "team_success": rows["team/success_rate"].tolist(), "episodes": episodes,
            "source": "results/reference/scenarios/baselines.csv"})
    return scores


def write_facts(reference: str | Path) -> Path:
    """``zoo.yaml`` again with the scores ``reference`` records (``recorded_scores``) in place of those it held: its
    header, training facts and README's scores kept. After a reference table is re-made:
    ``python -m sidewalk.partners.cards results/reference``."""
    import yaml

    recorded = recorded_scores(reference)
    kept = {name: {**({"trained": entry.facts["trained"]} if "trained" in entry.facts else {}),
                   "scores": [score for score in entry.scores() if score["source"] == README_SOURCE]
                   + recorded.get(name, [])}
            for name, entry in partners().items()}
    kept = {name: {key: value for key, value in fields.items() if value} for name, fields in kept.items()}
    header = "".join(line for line in FACTS_FILE.read_text().splitlines(keepends=True)
                     if line.startswith("#"))
    class Dumper(yaml.SafeDumper):  # mappings as blocks, a list of values on one line
        def represent_list(self, values):
            flat = all(not isinstance(value, (dict, list)) for value in values)
            return self.represent_sequence("tag:yaml.org,2002:seq", values, flow_style=flat)

    Dumper.add_representer(list, Dumper.represent_list)
    body = yaml.dump({"partners": {name: fields for name, fields in kept.items() if fields}}, Dumper=Dumper,
                     sort_keys=False, width=120, allow_unicode=True)
    FACTS_FILE.write_text(header + body)
    facts.cache_clear()
    return FACTS_FILE


if __name__ == "__main__":
    import sys

    print(write_facts(sys.argv[1] if len(sys.argv) > 1 else "results/reference"))
