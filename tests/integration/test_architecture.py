"""The import contracts of pyproject.toml ([tool.importlinter]): lint-imports,
as a developer runs it, finds every contract kept (the rules it cannot
check: tests/unit/test_architecture.py); and the style ([tool.ruff]): ruff
check finds nothing and ruff format would change nothing, as a developer
runs them."""

import subprocess
import sys
from pathlib import Path

from tests.fixtures import ROOT


def test_the_import_contracts_hold():
    lint_imports = Path(sys.executable).parent / "lint-imports"
    proc = subprocess.run([str(lint_imports), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert ", 0 broken." in proc.stdout, proc.stdout


def ruff(*args: str) -> subprocess.CompletedProcess:
    command = [str(Path(sys.executable).parent / "ruff"), *args, "--no-cache", "."]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_ruff_finds_nothing():
    proc = ruff("check")
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ruff_format_would_change_nothing():
    proc = ruff("format", "--check")
    assert proc.returncode == 0, proc.stdout + proc.stderr
