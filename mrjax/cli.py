"""The `mrjax` command line."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `mrjax` console script; returns the exit code."""
    parser = argparse.ArgumentParser(prog="mrjax", description=__doc__)
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("reproduce", help="reproduce the paper's study on the embedded data")
    args = parser.parse_args(argv)
    if args.command == "reproduce":
        print("mrjax reproduce: not yet available in this version.")
        return 0
    parser.print_help()
    return 0


if __name__ == "__main__":
    sys.exit(main())
