"""The ``morphspace`` command line.

Subcommands register themselves in ``COMMANDS``; each has an ``add_arguments(parser)`` and a
``run(args) -> int``. Errors in user input end with a one-line message and exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from server.commands import bench, blend, build, eval_params, play, synth
from server.commands import eval as eval_command
from server.commands import align, build_graph, eval_align, eval_graph, export, serve

COMMANDS = {
    "synth": synth,
    "build": build,
    "build-graph": build_graph,
    "blend": blend,
    "eval": eval_command,
    "bench": bench,
    "play": play,
    "eval-params": eval_params,
    "align": align,
    "eval-align": eval_align,
    "eval-graph": eval_graph,
    "serve": serve,
    "export": export,
}


def build_parser():
    parser = argparse.ArgumentParser(
        prog="morphspace",
        description="Parametric real-time animation of performance-captured mesh sequences.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        doc = (module.__doc__ or "").strip().splitlines()
        p = sub.add_parser(name, help=doc[0] if doc else None, description=(module.__doc__ or "").strip(),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return COMMANDS[args.command].run(args)
    except (ValueError, OSError) as exc:
        print(f"morphspace {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"morphspace {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
