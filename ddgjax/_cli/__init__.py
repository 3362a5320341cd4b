"""The `ddgjax` command line: `ddgjax flow` (curve-shortening flows, the reading report's Figure 3)
and `ddgjax info` (topology and curvature report of a mesh)."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ddgjax",
        description="Discrete differential geometry in JAX. Run a subcommand with --help for its options.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    from .curves._demo import add_flow_arguments

    add_flow_arguments(
        sub.add_parser(
            "flow",
            help="discrete curve-shortening flows A, B, D on a polygon (the report's Figure 3)",
            description="Evolve one polygon by the discrete curve-shortening flows and plot the invariants.",
        )
    )
    from .mesh._report import add_info_arguments

    add_info_arguments(
        sub.add_parser(
            "info",
            help="topology, area, volume, Gauss-Bonnet and curvature statistics of a mesh",
            description="Print the topology report and curvature statistics of a mesh.",
        )
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `ddgjax` console script."""
    import jax

    # Geometry wants float64; the CLI, like tests and notebooks, enables it explicitly (DESIGN.md).
    jax.config.update("jax_enable_x64", True)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return int(args.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
