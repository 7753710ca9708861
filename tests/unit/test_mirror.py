"""Pure parts of the lab's Docker-style apt mirror: no network, no engine."""

import dataclasses
import hashlib

import pytest

from tests.lab.mirror import (
    RULES,
    Alt,
    compare_versions,
    docker_version,
    format_relations,
    packages_entry,
    parse_paragraphs,
    parse_relations,
    release_date,
    release_text,
    rewrite_control,
    rules_digest,
    upstream_version,
)

RULE = {r.name: r for r in RULES}

DOCKER_IO = {
    "Package": "docker.io",
    "Version": "26.1.5+dfsg1-9+deb13u1",
    "Architecture": "amd64",
    "Maintainer": "Debian Go Packaging Team <team+pkg-go@tracker.debian.org>",
    "Installed-Size": "94954",
    "Depends": "libc6 (>= 2.34), libsystemd0, adduser, containerd (>= 1.4~), iptables, runc (>= 1.0.0~rc8~), tini",
    "Pre-Depends": "init-system-helpers (>= 1.54~)",
    "Recommends": "apparmor, ca-certificates, docker-cli, git, needrestart (>= 3.1~), xz-utils",
    "Conflicts": "docker-ce, docker-ce-rootless-extras",
    "Section": "admin",
    "Description": "Linux container runtime\n Docker complements kernel namespacing.",
}
DOCKER_CLI = {
    "Package": "docker-cli",
    "Source": "docker.io",
    "Version": "26.1.5+dfsg1-9+deb13u1",
    "Installed-Size": "30333",
    "Replaces": "docker.io (<< 26.1.4+dfsg1-7~)",
    "Depends": "libc6 (>= 2.34)",
    "Recommends": "docker-buildx",
    "Conflicts": "docker-ce-cli, podman-docker",
    "Breaks": "docker.io (<< 26.1.4+dfsg1-7~)",
    "Description": "Docker CLI",
}
CONTAINERD = {
    "Package": "containerd",
    "Version": "1.7.24~ds1-6+deb13u1",
    "Installed-Size": "118977",
    "Depends": "runc (>= 0.1.0~), libc6 (>= 2.34)",
    "Suggests": "containernetworking-plugins",
    "Breaks": "docker.io (<< 1.12)",
    "Description": "daemon to control runC",
}
RUNC = {
    "Package": "runc",
    "Source": "runc (1.1.15+ds1-2)",
    "Version": "1.1.15+ds1-2+b4",
    "Installed-Size": "10525",
    "Depends": "libc6 (>= 2.38), libseccomp2 (>= 2.5.0)",
    "Recommends": "criu",
    "Description": "Open Container Project - runtime",
}


def rels(value):
    return [str(g[0]) if len(g) == 1 else " | ".join(map(str, g)) for g in parse_relations(value)]


# ------------------------------------------------------------ versions


@pytest.mark.parametrize(
    "debian, upstream",
    [
        ("26.1.5+dfsg1-9+deb13u1", "26.1.5"),
        ("1.7.24~ds1-6+deb13u1", "1.7.24"),
        ("1.1.15+ds1-2+b4", "1.1.15"),
        ("0.13.1+ds1-3", "0.13.1"),
        ("2.26.1-4", "2.26.1"),
        ("1:2.0.1-2", "2.0.1"),
        ("3.0", "3.0"),
    ],
)
def test_upstream_version_strips_epoch_revision_and_repack_suffix(debian, upstream):
    assert upstream_version(debian) == upstream


def test_docker_versions_follow_dockers_scheme():
    assert docker_version(RULE["docker-ce"], "26.1.5+dfsg1-9+deb13u1") == "5:26.1.5-1~debian.13~trixie"
    assert docker_version(RULE["docker-ce-cli"], "26.1.5+dfsg1-9") == "5:26.1.5-1~debian.13~trixie"
    assert docker_version(RULE["containerd.io"], "1.7.24~ds1-6+deb13u1") == "1.7.24-1"
    assert docker_version(RULE["docker-compose-plugin"], "2.26.1-4") == "2.26.1-1~debian.13~trixie"


def test_epoch_5_outranks_any_debian_docker_io_version():
    assert compare_versions("5:26.1.5-1~debian.13~trixie", "26.1.5+dfsg1-9+deb13u1") > 0


@pytest.mark.parametrize(
    "a, b, expected",
    [
        ("1.0", "1.0~rc1", 1),
        ("2.38", "2.34", 1),
        ("1:0.1", "2.0", 1),
        ("1.0-1", "1.0-1+b1", -1),
        ("1.0~", "1.0", -1),
        ("1.0a", "1.0", 1),
        ("1.0", "1.0.0", -1),
        ("1.2.3", "1.2.3", 0),
    ],
)
def test_compare_versions_matches_dpkg(a, b, expected):
    assert compare_versions(a, b) == expected


# ------------------------------------------------------------ relations


def test_relations_roundtrip():
    value = "libc6 (>= 2.34), zfs-fuse | zfsutils-linux, foo:any"
    groups = parse_relations(value)
    assert groups[0] == [Alt("libc6", ">=", "2.34")]
    assert [a.name for a in groups[1]] == ["zfs-fuse", "zfsutils-linux"]
    assert format_relations(groups) == value


def test_relations_reject_garbage():
    with pytest.raises(ValueError):
        parse_relations("libc6 (>= 2.34")


# ------------------------------------------------------------ control rewriting


def test_docker_ce_depends_on_docker_names_without_debian_versions():
    ctl = rewrite_control(RULE["docker-ce"], [DOCKER_IO], "5:26.1.5-1~debian.13~trixie")
    depends = rels(ctl["Depends"])
    assert "containerd.io" in depends and "docker-ce-cli" in depends
    assert not {"containerd", "runc"} & {d.split()[0] for d in depends}
    assert depends.count("containerd.io") == 1  # containerd and runc both map to it
    assert "libc6 (>= 2.34)" in depends and "tini" in depends
    # the CLI moved from Recommends to Depends, needrestart is dropped
    assert rels(ctl["Recommends"]) == ["apparmor", "ca-certificates", "git", "xz-utils"]
    assert ctl["Pre-Depends"] == "init-system-helpers (>= 1.54~)"


def test_docker_ce_conflicts_replaces_provides_docker_io_only():
    ctl = rewrite_control(RULE["docker-ce"], [DOCKER_IO], "5:26.1.5-1~debian.13~trixie")
    assert ctl["Conflicts"] == "docker.io"  # Debian's "Conflicts: docker-ce" is gone
    assert ctl["Replaces"] == "docker.io"
    assert ctl["Provides"] == "docker.io"
    assert "Breaks" not in ctl


def test_identity_fields_and_order():
    ctl = rewrite_control(RULE["docker-ce"], [DOCKER_IO], "5:26.1.5-1~debian.13~trixie")
    assert list(ctl)[:6] == ["Package", "Source", "Version", "Architecture", "Maintainer", "Installed-Size"]
    assert list(ctl)[-1] == "Description"
    assert ctl["Package"] == "docker-ce"
    assert ctl["Source"] == "docker.io (26.1.5+dfsg1-9+deb13u1)"
    assert ctl["Version"] == "5:26.1.5-1~debian.13~trixie"
    assert "docker.io 26.1.5+dfsg1-9+deb13u1" in ctl["Description"]
    assert ctl["Description"].startswith("Linux container runtime\n Docker complements")


def test_cli_keeps_versioned_debian_relations_and_adds_its_own_name():
    ctl = rewrite_control(RULE["docker-ce-cli"], [DOCKER_CLI], "5:26.1.5-1~debian.13~trixie")
    assert rels(ctl["Conflicts"]) == ["podman-docker", "docker-cli"]
    assert rels(ctl["Replaces"]) == ["docker.io (<< 26.1.4+dfsg1-7~)", "docker-cli"]
    assert ctl["Breaks"] == "docker.io (<< 26.1.4+dfsg1-7~)"
    assert ctl["Provides"] == "docker-cli"
    assert rels(ctl["Recommends"]) == ["docker-buildx-plugin", "docker-compose-plugin"]
    assert ctl["Source"] == "docker.io (26.1.5+dfsg1-9+deb13u1)"


def test_containerd_io_merges_containerd_and_runc():
    ctl = rewrite_control(RULE["containerd.io"], [CONTAINERD, RUNC], "1.7.24-1")
    # runc is inside: no self-dependency, libc6 bounds merged to the stronger one
    assert rels(ctl["Depends"]) == ["libc6 (>= 2.38)", "libseccomp2 (>= 2.5.0)"]
    assert "Recommends" not in ctl  # criu dropped
    for field in ("Conflicts", "Replaces", "Provides"):
        assert rels(ctl[field]) == ["containerd", "runc"]
    assert ctl["Breaks"] == "docker.io (<< 1.12)"
    assert ctl["Installed-Size"] == str(118977 + 10525)
    assert ctl["Source"] == "containerd (1.7.24~ds1-6+deb13u1)"


def test_source_field_keeps_the_binnmu_source_version():
    rule = dataclasses.replace(RULE["containerd.io"], name="runc-only", sources=("runc",))
    ctl = rewrite_control(rule, [RUNC], "1.1.15-1")
    assert ctl["Source"] == "runc (1.1.15+ds1-2)"


def test_plugins_recommend_the_docker_cli():
    compose = {
        "Package": "docker-compose",
        "Version": "2.26.1-4",
        "Depends": "libc6 (>= 2.34)",
        "Recommends": "docker-cli",
        "Description": "compose",
    }
    ctl = rewrite_control(RULE["docker-compose-plugin"], [compose], "2.26.1-1~debian.13~trixie")
    assert ctl["Recommends"] == "docker-ce-cli"
    assert ctl["Provides"] == ctl["Conflicts"] == ctl["Replaces"] == "docker-compose"


def test_rules_digest_is_stable_and_covers_rules(monkeypatch):
    """The mirror is rebuilt when its digest changes: it must change with
    any field of any rule and with the suite, and stay put for equal rules."""
    from tests.lab import mirror

    digest = rules_digest()
    monkeypatch.setattr(mirror, "RULES", tuple(dataclasses.replace(rule) for rule in RULES))
    assert rules_digest() == digest  # equal rules, new objects: the same mirror
    changed = set()
    for index, rule in enumerate(RULES):
        for field in dataclasses.fields(rule):
            value = getattr(rule, field.name)
            other = (
                (not value)
                if isinstance(value, bool)
                else (value + ("x",) if isinstance(value, tuple) else f"{value}x")
            )
            edited = list(RULES)
            edited[index] = dataclasses.replace(rule, **{field.name: other})
            monkeypatch.setattr(mirror, "RULES", tuple(edited))
            changed.add(rules_digest())
    assert digest not in changed and len(changed) == sum(len(dataclasses.fields(rule)) for rule in RULES)
    monkeypatch.setattr(mirror, "RULES", RULES)
    monkeypatch.setattr(mirror, "SUITE", "forky")
    assert rules_digest() != digest


# ------------------------------------------------------------ deb822 / indexes


def test_parse_paragraphs_keeps_continuation_lines():
    text = "Package: a\nDescription: short\n long line\n .\n\nPackage: b\nVersion: 1\n"
    a, b = parse_paragraphs(text)
    assert a["Description"] == "short\n long line\n ."
    assert b == {"Package": "b", "Version": "1"}


def test_packages_entry_appends_file_fields():
    data = b"not really a deb"
    entry = packages_entry(
        {"Package": "x", "Version": "1", "Description": "d\n more"}, "pool/stable/amd64/x_1_amd64.deb", data
    )
    fields = parse_paragraphs(entry)[0]
    assert entry.startswith("Package: x\n")
    assert fields["Filename"] == "pool/stable/amd64/x_1_amd64.deb"
    assert fields["Size"] == str(len(data))
    assert fields["SHA256"] == hashlib.sha256(data).hexdigest()
    assert fields["MD5sum"] == hashlib.md5(data).hexdigest()
    assert fields["Description"] == "d\n more"


def test_release_lists_every_index_under_every_hash():
    indexes = {"stable/binary-amd64/Packages": b"abc", "stable/binary-amd64/Packages.gz": b"defg"}
    text = release_text(indexes, "Sat, 01 Feb 2025 10:00:00 UTC")
    fields = parse_paragraphs(text)[0]
    assert fields["Suite"] == fields["Codename"] == "trixie"
    assert fields["Components"] == "stable"
    assert fields["Architectures"] == "amd64 arm64"
    assert fields["Date"] == "Sat, 01 Feb 2025 10:00:00 UTC"
    for field, algo in (("MD5Sum", "md5"), ("SHA1", "sha1"), ("SHA256", "sha256"), ("SHA512", "sha512")):
        lines = fields[field].splitlines()[1:]
        assert [line.split() for line in lines] == [
            [hashlib.new(algo, data).hexdigest(), str(len(data)), path] for path, data in sorted(indexes.items())
        ]
        assert all(line.startswith(" ") for line in lines)


def test_release_date_is_rfc2822_in_utc():
    assert release_date(0) == "Thu, 01 Jan 1970 00:00:00 UTC"
    assert release_date(1700000000) == "Tue, 14 Nov 2023 22:13:20 UTC"
