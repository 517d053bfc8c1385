"""Walk the sidewalk yourself: a local web page where your keys drive one agent against any partner.

    sidewalk-play                                              # the grid, against the Dijkstra planner
    sidewalk-play env=continuous opponent=prm                  # the continuous world, against PRM
    sidewalk-play opponent=convention opponent.params.style=keep_right
    sidewalk-play opponent=policy opponent.path=results/runs/<RUN_DIR>     # a trained partner
    sidewalk-play env=continuous opponent=proxy opponent.params.dataset=sidewalk-play/continuous-prm-v0

``key=value`` arguments are config overrides as for runners/main.py (env, layout, noise, partner and its settings),
checked as it checks them. The page serves on 127.0.0.1 only unless --host says otherwise. An episode starts at your
first arrow or space. Keys: arrows (grid: one cell a press, held: one a step, none: the game waits; continuous:
up/down accelerate and brake, left/right turn), space pauses and resumes, R restarts. Every episode is saved to a
Minari dataset (docs/guide/datasets.md): --dataset-id, --datasets DIR, or --no-record. Guide: docs/guide/play.md.
"""

from __future__ import annotations

import argparse
import signal
import sys
import traceback
import webbrowser
from pathlib import Path


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="sidewalk-play", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog="\n".join(__doc__.splitlines()[2:]),
    )
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="config overrides (world and partner)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine)")
    parser.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: any free one)")
    parser.add_argument("--seed", type=int, default=0, help="the first episode's world seed (default 0)")
    parser.add_argument("--datasets", type=Path, help="Minari datasets folder (default: Minari's own)")
    parser.add_argument("--dataset-id", help="dataset of the episodes (default sidewalk-play/<env>-<partner>-v0)")
    parser.add_argument("--no-record", action="store_true", help="save no episodes")
    parser.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    parser.add_argument("--verbose", action="store_true", help="log every request")
    parser.add_argument("--traceback", action="store_true", help="show the traceback of an error")
    args = parser.parse_args(argv)
    bad = [item for item in args.overrides if "=" not in item]
    if bad:
        parser.error(f"{bad[0]!r} is not a key=value override")
    return args


def stop(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from sidewalk.play.command import build_server

    try:
        server = build_server(args.overrides, args.host, args.port, args.datasets, args.dataset_id,
                              record=not args.no_record, seed=args.seed, verbose=args.verbose)
    except (ValueError, OSError) as error:
        if args.traceback:
            traceback.print_exc()
        print(f"error: {error}", file=sys.stderr)
        return 2
    game = server.game.describe()
    print(f"sidewalk-play: {game['domain']} against {game['partner']} at {server.url} "
          f"(recording: {game['recording'] or 'off'}); Ctrl-C stops", flush=True)
    if not args.no_browser:
        webbrowser.open(server.url)
    signal.signal(signal.SIGTERM, stop)  # kill, like Ctrl-C, saves the episode under way
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("sidewalk-play: stopped", file=sys.stderr)
    finally:
        server.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
