"""``gatewaylab lesson NAME``: run a scripted CANopen lesson and print it (see lessons.py)."""

from __future__ import annotations

import argparse
from typing import Any

from gatewaylab.cli.lessons import LESSONS, run_lesson

__all__ = ["add_subcommand", "cmd_lesson"]


_DESCRIPTION = """\
Run a short CANopen scenario on a simulated bus and tell, step by step, what is sent, by whom, why,
and what changed in the receiving node; it ends with a sequence diagram. The output is the same on
every run. Each lesson has a page with exercises in docs/teaching/.

lessons:
""" + "".join(f"  {name:<8} {title}\n" for name, (title, _) in LESSONS.items()) + """
example:
  gatewaylab lesson lss
  gatewaylab lesson pdo --mermaid      # the diagram as mermaid, for a Markdown page
"""


def cmd_lesson(args: argparse.Namespace) -> int:
    """Print the lesson (every line through print, so it pipes like any text)."""
    run_lesson(args.name, print, mermaid=args.mermaid)
    return 0


def add_subcommand(subparsers: Any) -> None:
    """Add ``lesson`` to the gatewaylab CLI."""
    p = subparsers.add_parser("lesson", help="a scripted CANopen lesson (nmt, sdo, pdo, sync, emcy, lss, cia402)",
                              description=_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=sorted(LESSONS), metavar="NAME", help="one of: " + ", ".join(LESSONS))
    p.add_argument("--mermaid", action="store_true", help="print the sequence diagram as mermaid")
    p.set_defaults(func=cmd_lesson)
