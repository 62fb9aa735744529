"""Shared helper for the command-line tests: run ``pointrig`` in this process."""

from __future__ import annotations

import contextlib
import io

from pointrig.cli import main


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``pointrig ARGV`` in this process: its exit code, standard output and standard error."""
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        code = main(argv)
    return code, so.getvalue(), se.getvalue()
