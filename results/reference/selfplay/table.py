"""The self-play table of README.md here: one row per run folder given (searched recursively for metrics.csv).

    python results/reference/selfplay/table.py results/sweeps/selfplay_continuous --target 0.95
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd
from omegaconf import OmegaConf


def row(run: Path, target: float) -> dict:
    config = OmegaConf.load(run / "config.yaml")
    metrics = pd.read_csv(run / "metrics.csv")
    evaluations = metrics.dropna(subset=["eval/team/success_rate"])
    reached = evaluations[evaluations["eval/team/success_rate"] >= target]
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").exists() else {}
    final = evaluations.iloc[-1]
    return {
        "learner": f"{config.algo.name} ({config.opponent.name}, {config.env.domain}"
        + (f", {config.env.layout}" if config.env.get("layout", "sidewalk") != "sidewalk" else "")
        + (", Other-Play" if config.get("other_play", False) else "") + ")",
        "seed": int(config.seed),
        "final team success": round(float(summary.get("team/success_rate", final["eval/team/success_rate"])), 3),
        "final deadlock rate": summary.get("deadlock_rate", float("nan")),
        f"evaluations ≥ {target}": f"{len(reached)}/{len(evaluations)}",
        "first ≥ target: frames": f"{int(reached['frames'].iloc[0]):,}" if len(reached) else "–",
        "first ≥ target: s": round(float(reached["time_s"].iloc[0])) if len(reached) else "–",
        "frames run": f"{int(metrics['frames'].iloc[-1]):,}",
        "wall s": round(float(metrics["time_s"].iloc[-1])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+")
    parser.add_argument("--target", type=float, default=0.95)
    args = parser.parse_args()
    runs = sorted({path.parent for root in args.paths for path in Path(root).rglob("metrics.csv")})
    table = pd.DataFrame([row(run, args.target) for run in runs]).sort_values(["learner", "seed"])
    lines = [list(table.columns), ["---"] * len(table.columns), *table.astype(str).values.tolist()]
    print("\n".join("| " + " | ".join(map(str, line)) + " |" for line in lines))


if __name__ == "__main__":
    main()
