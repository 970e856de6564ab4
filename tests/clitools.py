"""The one way the tests run the command line: in-process (CliRunner) or as a real process."""

from __future__ import annotations

import json
import subprocess
import sys

from click.testing import CliRunner

from shapeidx.cli import main


def cli(*args, env=None):
    """Run shapeidx in-process (click's CliRunner); returns the result (stdout, stderr, exit_code)."""
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def cli_json(*args):
    result = cli(*args, "--json")
    assert result.exit_code == 0, result.output + result.stderr
    return json.loads(result.stdout)


def shapeidx_command(*args) -> list[str]:
    """A real ``shapeidx`` process (same interpreter as the tests)."""
    return [sys.executable, "-m", "shapeidx.cli", *map(str, args)]


def run_shapeidx(*args, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run(shapeidx_command(*args), capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(result, path, status=1):
    """A user error: status ``status``, one line on stderr naming ``path``, no traceback."""
    assert result.exit_code == status, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert str(path) in lines[0]
    assert "Traceback" not in result.stderr
