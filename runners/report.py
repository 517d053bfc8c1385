"""Report on run folders and sweeps: learning curves, training cost, final values with 95 % CIs, paper figures.

    python runners/report.py results/sweeps/2026-01-01_12-00-00_fig5_discrete
    python runners/report.py results/sweeps/a results/sweeps/b --out results/report
    python runners/report.py results/sweeps --x iterations --trajectories 0     # no replay of checkpoints
    python runners/report.py results/sweeps/reference --out results/reference --preamble notes.md

Writes report.md (tables, with Safety Gym's final return, final cost and training cost rate where runs record
costs; figures embedded, the learner's cumulative training cost among them; the cross-play matrix of any folder
with a crossplay.csv under the paths, see runners/crossplay.py), report.csv (every number in report.md),
curves.csv (every plotted point), marl_eval/*.json (the runs as marl-eval files laid out as BenchMARL writes its
runs, one per set that marl-eval loads whole; see sidewalk.report.marl_eval) and figures/ into --out (default:
report/ inside the single path given, or inside the paths' common folder). Unusable run folders are listed in report.md and skipped. Progress goes to
stderr. Exit status: 0, or 1 when no run could be used, 2 for bad arguments. See the sidewalk.report package.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

from sidewalk.report.document import write_report
from sidewalk.report.tables import X_AXES, Settings


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[2:]),
    )
    parser.add_argument(
        "paths", nargs="+", metavar="PATH", help="run folders or folders holding them (searched recursively)"
    )
    parser.add_argument("--out", help="output folder (default: PATH/report)")
    parser.add_argument(
        "--preamble",
        metavar="FILE",
        help="a Markdown file placed under the report's title (how the runs were made)",
    )
    parser.add_argument("--x", choices=tuple(X_AXES), default="frames", help="x axis of the learning curves")
    parser.add_argument(
        "--trajectories",
        type=int,
        default=3,
        metavar="K",
        help="episodes drawn per trajectory panel (Fig. 10), 0 to skip replaying checkpoints",
    )
    parser.add_argument("--max-panels", type=int, default=8, help="most conditions drawn in Fig. 10")
    parser.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples per interval")
    parser.add_argument("--confidence", type=float, default=0.95, help="confidence level of the intervals")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="report: %(message)s", stream=sys.stderr)

    try:
        settings = Settings(
            x=args.x,
            confidence=args.confidence,
            n_resamples=args.resamples,
            seed=args.seed,
            trajectory_episodes=args.trajectories,
            max_trajectory_panels=args.max_panels,
        )
    except ValueError as error:
        parser.error(str(error))
    start = time.perf_counter()
    try:
        result = write_report(args.paths, args.out, settings, args.preamble)
    except (FileNotFoundError, NotADirectoryError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(
        f"report: {result.report_md} ({len(result.figures)} figures, {len(result.skipped)} run folder(s) skipped, "
        f"{time.perf_counter() - start:.1f} s)",
        file=sys.stderr,
    )
    for note in result.notes:
        print(f"report: note: {note}", file=sys.stderr)
    return 0 if result.conditions or result.crossplay else 1


if __name__ == "__main__":
    import torch

    torch.set_num_threads(
        1
    )  # replaying small networks: one thread is fastest and leaves the other cores alone
    sys.exit(main())
