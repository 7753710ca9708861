"""The rules of ARCHITECTURE.md that import-linter cannot check: a role
reads another role's settings only through that role's hooks; no import
circle; no module over 400 lines.  The import contracts in pyproject.toml
(`lint-imports`) run in tests/integration/test_architecture.py: import-linter's
graph builder hangs in a process pyinfra's gevent has patched."""

from __future__ import annotations

import ast
import os

from robotfleet import deploy_roles
from tests.fixtures import ROOT

MAX_LINES = 400
NOT_THE_PRODUCT = {"tests", "docs", "build", "dist"}


def setting_reads(tree: ast.AST, names: set[str], not_data: frozenset = frozenset()):
    """(line, setting) for each read of a setting in ``names``: data.NAME,
    something.data.NAME, x.get("NAME"), value_of(x, "NAME"), getattr(x, "NAME"), x["NAME"];
    ``not_data``: names of variables that hold no host's data (x.get and
    x[...] on them are not reads)."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Call, ast.Subscript)) and _holder(node) in not_data:
            continue
        if isinstance(node, ast.Attribute) and node.attr in names:
            holder = node.value
            if (isinstance(holder, ast.Name) and holder.id == "data") or (
                isinstance(holder, ast.Attribute) and holder.attr == "data"
            ):
                yield node.lineno, node.attr
        elif isinstance(node, ast.Call) and node.args:
            function = node.func
            called = function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", None)
            key = (
                node.args[0]
                if called == "get"
                else node.args[1]
                if called in ("value_of", "getattr") and len(node.args) > 1
                else None
            )
            if isinstance(key, ast.Constant) and key.value in names:
                yield node.lineno, key.value
        elif isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) and node.slice.value in names:
            yield node.lineno, node.slice.value


def test_a_role_reads_only_its_own_settings():
    """Another role's setting is read through a function of that role's
    hooks.py (e.g. roles/payload/hooks.py wants_gpus), so the role that owns
    a setting decides what it means."""
    owner = {setting.name: role.name for role in deploy_roles.roles() for setting in role.settings}
    found = []
    for path in sorted((ROOT / "roles").rglob("*.py")):
        role = path.relative_to(ROOT / "roles").parts[0]
        others = {name for name, by in owner.items() if by != role}
        for line, name in setting_reads(ast.parse(path.read_text()), others):
            found.append(f"{path.relative_to(ROOT)}:{line}: {name} is a setting of the {owner[name]} role")
    assert found == []


def _holder(node) -> str | None:
    """The variable name ``x`` of ``x.get(...)`` or ``x[...]``."""
    target = (
        node.func.value
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
        else (node.value if isinstance(node, ast.Subscript) else None)
    )
    return target.id if isinstance(target, ast.Name) else None


# Variables of the engine that hold a status row, keyed by column (a role's
# column may share its setting's name: the PULL column), not a host's data.
ROWS = frozenset({"row"})


def test_the_engine_reads_no_role_s_setting():
    """robotfleet/ knows no role by name, nor any role's setting: what it
    needs of one it reads through the role's card; it reads by name only its
    own settings (robotfleet/fleet/connection.py, pull_mode.py)."""
    from robotfleet.fleet import connection, pull_mode

    # the allowlist: the engine's own settings
    own = {setting.name for setting in (*connection.SETTINGS, *pull_mode.SETTINGS)}
    owner = {
        setting.name: role.name for role in deploy_roles.roles() for setting in role.settings if setting.name not in own
    }
    found = []
    for path in sorted((ROOT / "robotfleet").rglob("*.py")):
        for line, name in setting_reads(ast.parse(path.read_text()), set(owner), ROWS):
            found.append(f"{path.relative_to(ROOT)}:{line}: {name} is a setting of the {owner[name]} role")
    assert found == []


def test_the_reads_found_are_the_ones_written():
    code = (
        'a = data.payload_gpu\nb = host.data.x11_enabled\nc = data.get("sensors", [])\n'
        'd = value_of(data, "x11_user")\ne = data["gpu"]\nf = plan.payload_gpu\ng = {"display": 1}\n'
    )
    reads = sorted(setting_reads(ast.parse(code), {"payload_gpu", "x11_enabled", "sensors", "x11_user", "gpu"}))
    assert reads == [(1, "payload_gpu"), (2, "x11_enabled"), (3, "sensors"), (4, "x11_user"), (5, "gpu")]
    rows = 'h = row.get("gpu")\ni = row["gpu"]\nj = data.get("gpu")\nk = getattr(data, "gpu", None)\n'
    assert list(setting_reads(ast.parse(rows), {"gpu"}, frozenset({"row"}))) == [(3, "gpu"), (4, "gpu")]


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other (strongly connected, more than one)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for imported in graph[module]:
            if imported not in index:
                visit(imported)
                low[module] = min(low[module], low[imported])
            elif imported in stack:
                low[module] = min(low[module], index[imported])
        if low[module] == index[module]:
            group = []
            while not group or group[-1] != module:
                group.append(stack.pop())
            if len(group) > 1:
                found.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return found


def test_circles_are_found():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def product_modules() -> dict[str, str]:
    """module name -> path, for every .py of the checkout but the tests'."""
    found = {}
    for directory, subdirectories, files in os.walk(ROOT):
        subdirectories[:] = sorted(
            d for d in subdirectories if not d.startswith(".") and d not in NOT_THE_PRODUCT and d != "__pycache__"
        )
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(directory, name)
                module = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                found[module.removesuffix(".__init__")] = path
    return found


def imported_by(path: str, module: str, known: set[str]) -> set[str]:
    """The checkout's modules ``module`` imports (also inside functions),
    each resolved to the longest known module name."""
    package = module if path.endswith("__init__.py") else module.rpartition(".")[0]
    targets = set()
    with open(path, encoding="utf-8") as source:
        tree = ast.parse(source.read())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            targets |= {base, *(f"{base}.{alias.name}" for alias in node.names)}
    resolved = set()
    for target in targets:
        while target and target not in known:
            target = target.rpartition(".")[0]
        if target and target != module:
            resolved.add(target)
    return resolved


def test_imports_are_resolved_to_the_checkouts_modules():
    imports = imported_by(
        str(ROOT / "roles" / "udev" / "passthrough.py"), "roles.udev.passthrough", set(product_modules())
    )
    assert imports == {
        "robotfleet",
        "robotfleet.checkers",
        "roles.payload.hooks",
        "roles.udev.rules",
        "roles.udev.settings",
    }


def test_no_import_circle():
    modules = product_modules()
    graph = {module: imported_by(path, module, set(modules)) for module, path in modules.items()}
    assert circles(graph) == []


def test_no_module_over_400_lines():
    over = []
    for directory, subdirectories, files in os.walk(ROOT):
        subdirectories[:] = [
            d for d in subdirectories if not d.startswith(".") and d not in NOT_THE_PRODUCT and d != "__pycache__"
        ]
        for name in files:
            if name.endswith(".py"):
                path = os.path.join(directory, name)
                with open(path, encoding="utf-8", errors="replace") as source:
                    lines = sum(1 for _ in source)
                if lines > MAX_LINES:
                    over.append(f"{os.path.relpath(path, ROOT)}: {lines} lines")
    assert over == []
