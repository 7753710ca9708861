"""robotfleet/pyinfra_private.py lists every private pyinfra name the code
uses, and each is still what it was: a pyinfra that removes one, or changes
the source it is pinned to, fails here naming it."""

from __future__ import annotations

import ast
import importlib

import pyinfra.api
import pytest

from robotfleet import pyinfra_patches, pyinfra_private
from tests.fixtures import ROOT

LISTED = {name for entry in pyinfra_private.USED for name in entry.names}
# pyinfra's own functions where robotfleet/pyinfra_patches.py has put its copies.
PYINFRAS_OWN = pyinfra_patches._ORIGINAL
PUBLIC_MODULES = ("pyinfra", "pyinfra.api", "pyinfra.api.exceptions")
PUBLIC_PACKAGES = ("pyinfra.operations", "pyinfra.facts")


@pytest.mark.parametrize("entry", pyinfra_private.USED, ids=lambda entry: entry.source)
def test_each_private_name_is_still_what_it_was(entry):
    for name in entry.names:
        try:
            pyinfra_private.resolve(name)
        except (ImportError, AttributeError):
            pytest.fail(f"pyinfra no longer has {name} ({entry.used_in}: {entry.why})")
    found = pyinfra_private.digest(PYINFRAS_OWN.get(entry.source) or pyinfra_private.resolve(entry.source))
    assert found == entry.digest, (
        f"pyinfra changed {entry.source} ({entry.used_in}: {entry.why}); check the code that uses it, "
        f"then pin {found} in robotfleet/pyinfra_private.py"
    )


def code_files():
    for top in ("robotfleet", "roles"):
        for path in sorted((ROOT / top).rglob("*.py")):
            if "payloadctl" not in path.parts:  # the robot side has no pyinfra
                yield path


def private_imports(tree: ast.AST) -> set[str]:
    """``module:name`` for each name imported from pyinfra that is private:
    an underscore name, anything of pyinfra_cli, a name of pyinfra.api's
    modules that pyinfra.api does not export."""
    found = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom) or node.level or not node.module:
            continue
        module = node.module
        for alias in node.names:
            name = alias.name
            if module.split(".")[0] == "pyinfra_cli" or (module.split(".")[0] == "pyinfra" and name.startswith("_")):
                found.add(f"{module}:{name}")
            elif (
                module.split(".")[0] == "pyinfra"
                and module not in PUBLIC_MODULES
                and not module.startswith(PUBLIC_PACKAGES)
            ):
                imported = getattr(importlib.import_module(module), name, None)
                if imported is None or getattr(pyinfra.api, name, None) is not imported:
                    found.add(f"{module}:{name}")
    return found


def private_attributes(tree: ast.AST) -> set[str]:
    """Underscore attributes read or written on something (not dunders)."""
    return {
        node.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
    }


def defined(tree: ast.AST) -> set[str]:
    """Underscore names the code defines itself: functions, methods, class
    fields and attributes it assigns (self._x = ...)."""
    names = {node.name for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names.add(target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", ""))
    return {name for name in names if name.startswith("_")}


def listed(name: str) -> bool:
    """``name`` is listed, or is a module some listed name is in."""
    module, _, attribute = name.partition(":")
    return name in LISTED or any(entry.startswith(f"{module}.{attribute}:") for entry in LISTED)


def test_every_private_pyinfra_name_the_code_uses_is_listed():
    listed_attributes = {name.rpartition(".")[2].rpartition(":")[2] for name in LISTED} | {
        "_host_keys",
        "_host_keys_filename",
        "_ssh_config",  # set by the listed SSHClient.connect, load_host_keys
        "_policy",
        "_trusted_set",
    }  # set by the listed set_missing_host_key_policy, Updater.__init__
    trees = {path: ast.parse(path.read_text()) for path in code_files()}
    # sys's, os's, and CPython _ssl's (robotfleet/pull/robot/https_request.py: it falls back to git where
    # they differ, tests/integration/test_pull_https_request.py)
    stdlib = {"_getframe", "_exit", "_SSLContext", "_wrap_socket"}
    # argparse's, which has no public walk of a parser's arguments: robotfleet/commands/completion.py and
    # manual.py read them as shtab itself does (tests/unit/test_command_lines.py, test_shell_completion.py)
    stdlib |= {"_actions", "_SubParsersAction", "_HelpAction", "_choices_actions", "_mutually_exclusive_groups"}
    ours = stdlib | {name for tree in trees.values() for name in defined(tree)}
    unlisted = []
    for path, tree in trees.items():
        unlisted += [f"{path.relative_to(ROOT)}: {name}" for name in sorted(private_imports(tree)) if not listed(name)]
        unlisted += [
            f"{path.relative_to(ROOT)}: .{name}" for name in sorted(private_attributes(tree) - listed_attributes - ours)
        ]
    assert unlisted == []


def test_the_scan_sees_a_private_import():
    tree = ast.parse(
        "from pyinfra.api.util import format_text, "
        "make_hash\nfrom pyinfra.api.command import StringCommand\n"
        "from pyinfra_cli.util import load_deploy_file\nfrom pyinfra.connectors.ssh_util import _x\n"
        "from pyinfra.facts.files import File\nclient._secret = 1\n"
    )
    assert private_imports(tree) == {
        "pyinfra.api.util:format_text",
        "pyinfra.api.util:make_hash",
        "pyinfra_cli.util:load_deploy_file",
        "pyinfra.connectors.ssh_util:_x",
    }
    assert private_attributes(tree) == {"_secret"}


def test_a_changed_or_removed_name_is_seen(monkeypatch):
    """A pyinfra that changes format_text, then one that drops it."""
    import pyinfra.api.util

    entry = next(entry for entry in pyinfra_private.USED if entry.source == "pyinfra.api.util:format_text")
    assert pyinfra_private.digest(pyinfra_private.resolve(entry.source)) == entry.digest
    monkeypatch.setattr(pyinfra.api.util, "format_text", lambda text, *args, **kwargs: text)
    assert pyinfra_private.digest(pyinfra_private.resolve(entry.source)) != entry.digest
    monkeypatch.delattr(pyinfra.api.util, "format_text")
    with pytest.raises(AttributeError):
        pyinfra_private.resolve(entry.source)
