"""The lab's Debian archive comes from this machine's apt sources (one-line
and deb822 formats), ROBOT_LAB_DEBIAN_URL overriding it."""

import pytest

from tests.lab import debian_archive
from tests.lab.debian_archive import ArchiveError, Source, debian_archive_url

DEB822 = """\
# a proxy for the robots' network
Types: deb deb-src
URIs: http://proxy.lan:3142/debian/
Suites: trixie trixie-updates
Components: main contrib
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg

Types: deb
URIs: http://proxy.lan:3142/debian-security
Suites: trixie-security
Components: main
"""


def apt_dir(tmp_path, sources_list=None, parts=None):
    (tmp_path / "sources.list.d").mkdir()
    if sources_list is not None:
        (tmp_path / "sources.list").write_text(sources_list)
    for name, text in (parts or {}).items():
        (tmp_path / "sources.list.d" / name).write_text(text)
    return tmp_path


def test_one_line_format_with_options_and_comments():
    text = (
        "# deb http://old.lan/debian bookworm main\n"
        "deb-src http://src.lan/debian trixie main\n"
        "deb [arch=amd64 signed-by=/usr/share/keyrings/k.gpg] http://mirror.lan/debian trixie main non-free # lan\n"
    )
    assert debian_archive.parse_one_line_style(text, "s.list") == [
        Source("deb-src", "http://src.lan/debian", "trixie", ("main",), "s.list:2"),
        Source("deb", "http://mirror.lan/debian", "trixie", ("main", "non-free"), "s.list:3"),
    ]


def test_deb822_format_stanzas_types_and_continuations():
    text = DEB822 + "\nTypes: deb\nURIs: http://off.lan/debian\nSuites: trixie\nComponents: main\nEnabled: no\n"
    text += "\nTypes: deb\nURIs:\n http://cont.lan/debian\nSuites: sid\nComponents: main\n"
    sources = debian_archive.parse_deb822_style(text, "d.sources")
    assert [(s.type, s.uri, s.suite) for s in sources] == [
        ("deb", "http://proxy.lan:3142/debian/", "trixie"),
        ("deb", "http://proxy.lan:3142/debian/", "trixie-updates"),
        ("deb-src", "http://proxy.lan:3142/debian/", "trixie"),
        ("deb-src", "http://proxy.lan:3142/debian/", "trixie-updates"),
        ("deb", "http://proxy.lan:3142/debian-security", "trixie-security"),
        ("deb", "http://cont.lan/debian", "sid"),
    ]
    assert sources[0].components == ("main", "contrib") and sources[0].origin == "d.sources:2"


def test_url_from_a_deb822_file(tmp_path):
    d = apt_dir(tmp_path, parts={"debian.sources": DEB822, "zz.list.disabled": "deb http://x.lan/debian trixie main\n"})
    assert debian_archive_url(d, {}) == "http://proxy.lan:3142/debian"


def test_url_from_sources_list_comes_first(tmp_path):
    d = apt_dir(tmp_path, "deb http://first.lan/debian bookworm main\n", {"debian.sources": DEB822})
    assert debian_archive_url(d, {}) == "http://first.lan/debian"


def test_other_distributions_and_security_archives_are_not_the_debian_archive(tmp_path):
    d = apt_dir(
        tmp_path,
        "deb http://archive.ubuntu.com/ubuntu noble main\n",
        {
            "security.list": "deb http://security.debian.org/debian-security bookworm-security main\n",
            "nodesource.sources": "Types: deb\nURIs: https://deb.nodesource.com/node_20.x\n"
            "Suites: nodistro\nComponents: main\n",
        },
    )
    assert debian_archive_url(d, {}) == "http://deb.debian.org/debian"


def test_environment_overrides_the_sources(tmp_path):
    d = apt_dir(tmp_path, parts={"debian.sources": DEB822})
    assert debian_archive_url(d, {"ROBOT_LAB_DEBIAN_URL": "https://deb.lan/debian/"}) == "https://deb.lan/debian"
    with pytest.raises(ArchiveError, match="ROBOT_LAB_DEBIAN_URL='deb.lan/debian': expected an http"):
        debian_archive_url(d, {"ROBOT_LAB_DEBIAN_URL": "deb.lan/debian"})


def test_recipe_hash_follows_the_url_and_only_the_url(hostimage, monkeypatch):
    monkeypatch.setenv("ROBOT_LAB_DEBIAN_URL", "http://deb.debian.org/debian")
    default = hostimage.base_tag()
    monkeypatch.setenv("ROBOT_LAB_DEBIAN_URL", "http://deb.debian.org/debian/")
    assert hostimage.base_tag() == default  # same archive, same image: no rebuild
    monkeypatch.setenv("ROBOT_LAB_DEBIAN_URL", "http://proxy.lan:3142/debian")
    assert hostimage.base_tag() != default
    assert hostimage.base_recipe()["mirror"] == "http://proxy.lan:3142/debian"


def test_mirror_builder_reads_packages_from_the_same_archive(tmp_path, monkeypatch):
    from tests.lab import mirror

    monkeypatch.setenv("ROBOT_LAB_DEBIAN_URL", "http://proxy.lan:3142/debian")
    apt = mirror.TrixieApt(tmp_path)
    assert " http://proxy.lan:3142/debian trixie main" in apt.sources.read_text()
