"""Adding a role is its folder plus one line of deploy.py's ROLES, then
`robotfleet generate`: the role links of docs/README.md and
docs/reference/roles.md (which test_docs_layout asks for) are written from
the roles, never by hand."""

from __future__ import annotations

import pytest

from robotfleet import deploy_roles
from robotfleet.commands import generate
from robotfleet.role import Role


def test_the_shipped_role_links_are_what_generate_writes():
    written = generate.generated()
    for path in (generate.INDEX, generate.ROLES_DOC):
        assert path.read_text() == written[path], f"{path.name} is stale: run robotfleet generate"


def test_a_role_added_to_deploy_py_gets_its_links_from_generate(tmp_path, monkeypatch):
    roles = (*deploy_roles.roles(), Role(name="lidar", doc="Lidar drivers and their udev names."))
    monkeypatch.setattr(deploy_roles, "registry", lambda *_: deploy_roles.registry_of(roles))  # deploy.py + "lidar"
    written = generate.generated()
    index, listed = written[generate.INDEX], written[generate.ROLES_DOC]
    assert "[lidar](../roles/lidar/README.md)" in index
    assert "- **lidar** ([roles/lidar](../../roles/lidar/README.md)): Lidar drivers and their udev names.\n" in listed
    assert listed.index("**Pull**") < listed.index("**lidar**")  # in the order deploy.py runs them
    for role in roles:
        assert f"](../roles/{role.name}/README.md)" in index and f"](../../roles/{role.name}/README.md)" in listed


def test_the_links_are_written_between_the_markers_only(tmp_path, monkeypatch):
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text(f"# Page\n\n- roles:\n  {generate.BEGIN}\n  old line\n  {generate.END}\n\nkept\n")
    monkeypatch.setattr(generate, "CHECKOUT", tmp_path)
    assert generate.between_markers(page, ["a", "b"]) == (
        f"# Page\n\n- roles:\n  {generate.BEGIN}\n  a\n  b\n  {generate.END}\n\nkept\n"
    )
    page.write_text("# Page\n")
    with pytest.raises(SystemExit, match="docs/page.md: no lines"):
        generate.between_markers(page, ["a"])


def test_a_long_settings_table_splits_by_the_settings_first_word():
    from types import SimpleNamespace as S

    short = [S(name=f"payload_{i}") for i in range(3)] + [S(name="ros_x")]
    assert generate.tables(short) == [(None, short)]
    long = [S(name=f"payload_{i}") for i in range(generate.TABLE_ROWS)] + [S(name="ros_x")]
    assert [(heading, len(members)) for heading, members in generate.tables(long)] == [
        ("`payload_...`", generate.TABLE_ROWS),
        ("`ros_...`", 1),
    ]
    one_word = [S(name=f"payload_{i}") for i in range(generate.TABLE_ROWS + 1)]
    assert generate.tables(one_word) == [(None, one_word)]
