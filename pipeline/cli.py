"""Shared command-line plumbing for the stage modules."""
from __future__ import annotations

import argparse
import sys
from typing import Callable, Sequence

from pipeline.errors import PipelineError


def run(main: Callable[[Sequence[str] | None], None], argv: Sequence[str] | None = None) -> None:
    """Run a stage's `main`, turning `PipelineError` into `error: ...` on stderr and exit status 2."""
    try:
        main(argv)
    except PipelineError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
