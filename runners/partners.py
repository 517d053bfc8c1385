"""The zoo of named partners: list them, show one's card, export a learned one's policy (sidewalk.partners.zoo).

    python runners/partners.py list                                # one line a partner, its name first
    python runners/partners.py show discrete/vdn_seed0             # its card (a Hugging Face model card)
    python runners/partners.py export continuous/mappo_seed1 --format onnx --out mappo_seed1.onnx

Installed, the command is `sidewalk-partners`. A partner is one config choice away in training, cross-play and the
play page: `opponent=zoo opponent.params.name=NAME`, `--partners zoo:NAME`. The ONNX file takes the observation
`gymnasium.make` gives the partner's agent in its world and returns that agent's action (the card says which
keywords). Exit status: 0, or 2 with one `error:` line for a bad name, format, agent or output path, before any work.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sidewalk-partners", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog="\n".join(__doc__.splitlines()[2:]),
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="{list,show,export}")
    commands.add_parser("list", help="every partner, one line each: name, kind, domains, split, score with itself")
    show = commands.add_parser("show", help="a partner's card")
    show.add_argument("name", help="a partner's name (see list)")
    export = commands.add_parser("export", help="a learned partner's policy alone, as a file")
    export.add_argument("name", help="a learned partner's name (see list)")
    export.add_argument("--format", default="onnx", help="the file's format (onnx, the one there is)")
    export.add_argument("--out", required=True, type=Path, help="the file to write")
    export.add_argument("--agent", type=int, default=1, help="the agent whose observation it takes (default 1)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from sidewalk.partners import cards, zoo

    try:
        if args.command == "list":
            for entry in zoo.partners().values():
                print(cards.list_line(entry))
            return 0
        if args.command == "show":
            print(cards.card(args.name), end="")
            return 0
        check_export(args, zoo)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return export(args, zoo)


def check_export(args: argparse.Namespace, zoo) -> None:
    """Every argument of ``export`` checked before the policy is built: ``ValueError`` naming the bad one."""
    if args.format not in zoo.EXPORT_FORMATS:
        raise ValueError(f"--format={args.format!r} is not valid; valid: {', '.join(map(repr, zoo.EXPORT_FORMATS))}")
    entry = zoo.learned_partner(args.name)
    if not args.out.parent.is_dir():
        raise ValueError(f"--out={str(args.out)!r}: its folder {str(args.out.parent)!r} does not exist")
    agents = range(zoo.read_partner(entry.folder).world.n_agents)  # its policy.pt's world, read, not yet built
    if args.agent not in agents:
        raise ValueError(f"--agent={args.agent} is not valid; valid: {', '.join(map(str, agents))}")
    missing = [name for name in ("onnx", "onnxscript") if not module_found(name)]
    if missing:
        raise ValueError(f"export needs {' and '.join(missing)}: pip install 'sidewalk-problem[onnx]'")


def module_found(name: str) -> bool:
    from importlib.util import find_spec

    return find_spec(name) is not None


def export(args: argparse.Namespace, zoo) -> int:
    import torch

    torch.set_num_threads(1)  # a small network: one thread is fastest here
    path = zoo.export_onnx(args.name, args.out, agent=args.agent)
    print(f"sidewalk-partners: {args.name} (agent {args.agent}) -> {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
