"""Cross-play: every trained policy (rows) with every partner (columns) on the same seeded evaluation worlds.

    python runners/crossplay.py results/sweeps/dqn_random results/sweeps/iql_self --out results/crossplay
    python runners/crossplay.py RUN_DIR... --partners random,dijkstra,OTHER_RUN_DIR --episodes 256 --seed 0
    python runners/crossplay.py RUN_DIR... --partners dijkstra --nominal --out DIR  # on the paper's fixed starts
    python runners/crossplay.py --redraw results/crossplay       # figures and report.md again (after notes.md)
    python runners/crossplay.py --train-best-responses discrete --out results/reference/adhoc/discrete
                                                                  # BR-Prox's best responses, cached beside the matrix

A RUN_DIR is a run folder with policy.pt, or a sweep folder standing for every run in it. Partners (default
scripted,rows): scripted opponents by name, `scripted` (every one of the rows' domain), `rows` (every row's run),
`heldout` (the held-out partner population: the ad-hoc score, docs/guide/adhoc.md), `zoo:NAME` (a partner of the
zoo by name: `sidewalk-partners list`), run or sweep folders, and a scripted opponent with settings,
NAME:KEY=VALUE[:KEY=VALUE...] (dijkstra:tie_break=progress: version 1). A row plays the agent it trained as; the
partner plays every other agent; both act greedily.
Every cell plays one episode in each of --episodes worlds seeded --seed + 1000003 (the stream a run of that seed
is evaluated on), in the first row's training world at --noise (default: the rows' training noise when they agree),
with --nominal from the scenario's own starts and goals (eval=nominal) whatever protocol the rows trained under.

Writes into --out: crossplay.csv (one row per pairing), crossplay.json (how it was made), figures/ (heatmaps of
success, collisions and team success, by run and by condition) and report.md (the section runners/report.py also
includes), and with `heldout` adhoc.csv (each condition's team success with the held-out partners: IQM over
seeds × partners, 95 % interval). Put what the matrix shows in --out/notes.md and --redraw. Exit status: 0, or 2
for bad arguments or a pairing that cannot be played (a missing policy.pt, an unknown partner, a run of another domain or scenario).
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
import time
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[2:]),
    )
    parser.add_argument("runs", nargs="*", metavar="RUN_DIR", help="run folders (with policy.pt) or sweep folders")
    parser.add_argument(
        "--partners",
        default="scripted,rows",
        help="comma-separated: scripted opponents' names (with settings: NAME:KEY=VALUE[:KEY=VALUE...]), "
        "'scripted', 'rows', 'heldout' (the held-out partner population), 'zoo:NAME' (a zoo partner), run or sweep "
        "folders (default: scripted,rows)",
    )
    parser.add_argument("--out", help="output folder (required unless --redraw)")
    parser.add_argument("--episodes", type=int, default=256, help="episodes per cell, one per world (default 256)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the evaluation worlds (default 0)")
    parser.add_argument("--noise", type=float, help="evaluation noise (default: the rows' training noise)")
    parser.add_argument("--nominal", action="store_true",
                        help="play every cell from the scenario's own starts and goals (the paper's evaluation, "
                             "eval=nominal), also for rows trained under eval=perturbed")
    parser.add_argument("--device", default="cpu", help="torch device (default cpu)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1: small networks)")
    parser.add_argument("--redraw", metavar="DIR", help="only redraw DIR's figures and report.md from its CSV")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--best-responses", nargs="+", metavar="RUN_OR_SWEEP",
                        help="with --redraw DIR: runs trained against held-out partners, evaluated with them and "
                             "written into DIR's best_responses.csv (BR-Prox beside the ad-hoc score)")
    parser.add_argument("--train-best-responses", metavar="DOMAIN",
                        help="train a best response to each held-out member of DOMAIN missing from --out DIR's "
                             "best_responses.csv, evaluate it with that member and add its row (resumable)")
    parser.add_argument("--members", help="with --train-best-responses: comma-separated held-out members (default all)")
    parser.add_argument("--runs-dir", default="results/best_responses",
                        help="with --train-best-responses: where the runs go, RUNS_DIR/DOMAIN/MEMBER "
                             "(default results/best_responses)")
    parser.add_argument("--seeds", type=int, default=1, help="with --train-best-responses: seeds each (default 1)")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                        help="with --train-best-responses: a config override for every best response (repeatable)")
    parser.add_argument("--iterations", type=int,
                        help="with --train-best-responses: training iterations (default: the learner's reference budget)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="crossplay: %(message)s", stream=sys.stderr)
    if args.train_best_responses:
        return train_best_responses(parser, args)
    if args.redraw:
        return redraw(parser, args)
    if args.best_responses:
        parser.error("--best-responses goes with --redraw DIR (the matrix whose partners they answer)")
    if not args.runs:
        parser.error("give at least one RUN_DIR (or --redraw DIR)")
    if not args.out:
        parser.error("--out DIR is required")
    if args.episodes < 1:
        parser.error(f"--episodes={args.episodes} must be at least 1")
    return play_matrix(args, argv)


def redraw(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--redraw DIR``: DIR's figures and report again, after adding ``--best-responses`` runs where given."""
    from sidewalk.report.crossplay import CROSSPLAY_CSV, write_crossplay_report

    if args.runs:
        parser.error("--redraw takes no RUN_DIR")
    if not (Path(args.redraw) / CROSSPLAY_CSV).exists():
        print(f"error: {args.redraw} has no {CROSSPLAY_CSV}", file=sys.stderr)
        return 2
    if args.best_responses and write_best_responses(args.redraw, args.best_responses) != 0:
        return 2
    print(f"crossplay: {write_crossplay_report(args.redraw)}", file=sys.stderr)
    return 0


def play_matrix(args: argparse.Namespace, argv: list[str] | None) -> int:
    """Every row with every partner, written into ``--out``; 2 with one error line for a pairing that cannot be
    played."""
    import torch

    from sidewalk.crossplay import run_crossplay, write_matrix
    from sidewalk.report.crossplay import CROSSPLAY_CSV

    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    try:
        matrix = run_crossplay(
            args.runs, args.partners, episodes=args.episodes, seed=args.seed, noise=args.noise,
            device=args.device, show_progress=not args.no_progress, nominal=args.nominal,
        )
    except ValueError as error:  # CrossplayError: a missing policy.pt, an unknown partner, a mismatching run
        print(f"error: {error}", file=sys.stderr)
        return 2
    wall_clock_s = time.perf_counter() - start
    command = "python runners/crossplay.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    report = write_matrix(matrix, args.out, command, wall_clock_s)
    print(f"crossplay: {Path(args.out) / CROSSPLAY_CSV} ({len(matrix.frame)} cells, {wall_clock_s:.1f} s), {report}",
          file=sys.stderr)
    return 0


def write_best_responses(folder: str, runs: list[str]) -> int:
    """The best-response runs evaluated into ``folder/best_responses.csv``; 2 with one error line where they do not
    fit."""
    from sidewalk.best_responses import best_responses_from_runs, write_cache

    try:
        write_cache(folder, best_responses_from_runs(runs))
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


def train_best_responses(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--train-best-responses DOMAIN --out DIR``: the package's ``train_best_responses``, then DIR's report
    redrawn where DIR holds a matrix; 2 with one error line for bad input, before any training."""
    if args.runs or args.redraw or args.best_responses:
        parser.error("--train-best-responses takes --out DIR and no RUN_DIR, --redraw or --best-responses")
    if not args.out:
        parser.error("--out DIR is required: the folder of best_responses.csv (the matrix's)")
    import torch

    from sidewalk.best_responses import train_best_responses as train
    from sidewalk.report.crossplay import CROSSPLAY_CSV, write_crossplay_report
    from sidewalk.stops import RunInterrupted

    torch.set_num_threads(args.threads)
    members = [name.strip() for name in args.members.split(",") if name.strip()] if args.members else None
    try:
        path = train(args.train_best_responses, args.out, args.runs_dir, members, seeds=args.seeds,
                     iterations=args.iterations, episodes=args.episodes, seed=args.seed,
                     show_progress=not args.no_progress, extra=args.override)
    except (ValueError, TypeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except RunInterrupted as stopped:  # the same command continues it: cached members are skipped, the run resumed
        print(f"\n{stopped.checkpointed}; run the same command again to continue", file=sys.stderr)
        return 128 + stopped.signum
    print(f"crossplay: {path}", file=sys.stderr)
    if (Path(args.out) / CROSSPLAY_CSV).exists():
        print(f"crossplay: {write_crossplay_report(args.out)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
