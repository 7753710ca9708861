"""The import contracts of pyproject.toml ([tool.importlinter]): lint-imports,
as a developer runs it, finds every contract kept (the rules it cannot
check: tests/unit/test_architecture.py); and the style rules ([tool.ruff]):
ruff check, as a developer runs it, finds nothing."""

import subprocess
import sys
from pathlib import Path

from tests.fixtures import ROOT


def test_the_import_contracts_hold():
    lint_imports = Path(sys.executable).parent / "lint-imports"
    proc = subprocess.run([str(lint_imports), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert ", 0 broken." in proc.stdout, proc.stdout


def test_ruff_finds_nothing():
    ruff = Path(sys.executable).parent / "ruff"
    proc = subprocess.run([str(ruff), "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
