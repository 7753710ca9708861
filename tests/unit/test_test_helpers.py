"""A helper that more than one test module needs lives in a helper module
(not named test_*.py), so a test module is never imported for its helpers:
its tests would run again under another name, its fixtures leak, and moving
a test would break a stranger."""

from __future__ import annotations

import ast

from tests.fixtures import ROOT

# Not moved yet: pull mode's tests, while pull mode's code is reshaped (issue 53 item 1).
PENDING = {
    ("tests/integration/test_pull_export_medium.py", "tests.integration.test_pull_media"),
    ("tests/integration/test_pull_export_medium.py", "tests.integration.test_pull_publish"),
    ("tests/integration/test_pull_media.py", "tests.integration.test_pull_publish"),
    ("tests/integration/test_pull_media.py", "tests.integration.test_pull_trust"),
    ("tests/integration/test_pull_media_network.py", "tests.integration.test_pull_media"),
    ("tests/integration/test_pull_report_copy.py", "tests.integration.test_pull_report_shards"),
    ("tests/integration/test_pull_stalled_remote.py", "tests.integration.test_pull_transport"),
    ("tests/e2e/test_pull_from_nothing.py", "tests.e2e.test_pull"),
    ("tests/e2e/test_pull_https.py", "tests.e2e.test_pull"),
    ("tests/e2e/test_pull_https.py", "tests.e2e.test_pull_media"),
    ("tests/e2e/test_pull_media.py", "tests.e2e.test_pull"),
}


def imported_test_modules(path) -> set[str]:
    """The test_*.py modules of tests/ that ``path`` imports (any depth, any form)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tests."):
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        for name in names:
            if name.startswith("tests.") and name.rsplit(".", 1)[-1].startswith("test_"):
                found.add(name)
    own = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    return found - {own}


def test_no_test_module_is_imported_for_its_helpers():
    imports = {
        (path.relative_to(ROOT).as_posix(), module)
        for path in sorted((ROOT / "tests").rglob("*.py"))
        for module in imported_test_modules(path)
    }
    assert imports - PENDING == set(), "move what they import into a helper module (tests/fixtures.py or beside them)"
    assert PENDING <= imports, f"no longer imported, take them off PENDING: {sorted(PENDING - imports)}"


def test_an_import_of_a_test_module_is_found(tmp_path, monkeypatch):
    path = ROOT / "tests" / "unit" / "x.py"
    monkeypatch.setattr(type(path), "read_text", lambda self: "from tests.unit.test_waves import result\n")
    assert imported_test_modules(path) == {"tests.unit.test_waves"}
    monkeypatch.setattr(type(path), "read_text", lambda self: "from tests.unit import test_waves, samples\n")
    assert imported_test_modules(path) == {"tests.unit.test_waves"}
