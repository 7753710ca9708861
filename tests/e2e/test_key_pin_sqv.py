"""End to end, issue 17 item 1 on a Debian 13 robot: apt 3 verifies with
sqv, which reads an armored Signed-By file its own way again.  Some key
files gpg lists as only the pinned key make sqv trust a hidden second key;
the key script installs gpg's own export of the pinned key instead, which
sqv reads as exactly that key.  Judged by the robot's real apt-get update
(private configuration) against local repositories signed by each key."""

from __future__ import annotations

import base64
import io
import tarfile

import pytest

from robotfleet.host import aptrepo
from tests import armor
from tests.unit.harness import docker_repo

pytestmark = pytest.mark.e2e

HOST = "robot1"
WORK = "/root/keypin"


@pytest.fixture(scope="module")
def on_robot(lab, tmp_path_factory):
    """The keys, the two repositories and every variant, unpacked on the robot in WORK."""
    home = tmp_path_factory.mktemp("signers")
    home.chmod(0o700)
    fprs, armored = armor.signers(home)
    base = tmp_path_factory.mktemp("keypin")
    for name, fpr in fprs.items():
        armor.repository(home, fpr, base / "repos" / name)
    (base / "variants").mkdir()
    for n, name in enumerate(sorted(armor.VARIANTS)):
        (base / "variants" / f"{n}.asc").write_bytes(armor.variant(name, armored))
    (base / "pinned.asc").write_text(armored["pinned"])
    packed = io.BytesIO()
    with tarfile.open(fileobj=packed, mode="w:gz") as tar:
        tar.add(base, arcname=".")
    lab.ok(
        HOST,
        f"rm -rf {WORK} && mkdir -p {WORK} && echo {base64.b64encode(packed.getvalue()).decode()} "
        f"| base64 -d | tar -xz -C {WORK}",
    )
    assert "sqv" in lab.ok(HOST, "apt-get --version | head -1; command -v sqv")
    yield fprs, {name: f"{WORK}/variants/{n}.asc" for n, name in enumerate(sorted(armor.VARIANTS))}
    lab.sh(HOST, f"rm -rf {WORK}")


def _offered(lab, key_file: str, signer: str, label: str) -> bool:
    work = f"{WORK}/apt-{label}-{signer}"
    return armor.parse_check(lab.sh(HOST, armor.apt_check_script(key_file, f"{WORK}/repos/{signer}", work))[1])


def test_sqv_itself_trusts_keys_gpg_does_not_list(lab, on_robot):
    """The blind spot on Debian 13 (gpg 2.4, sqv 1.3): if this stops holding,
    the variants no longer test anything on this path."""
    fprs, files = on_robot
    assert _offered(lab, f"{WORK}/pinned.asc", "pinned", "plain")
    assert not _offered(lab, f"{WORK}/pinned.asc", "intruder", "plain")
    for name in armor.SQV_TRUSTS_HIDDEN:
        lines = lab.ok(
            HOST,
            f"h=$(mktemp -d); GNUPGHOME=$h gpg --batch --show-keys --with-colons {files[name]} 2>/dev/null; rm -rf $h",
        ).splitlines()
        assert [lines[n + 1].split(":")[9] for n, line in enumerate(lines) if line.startswith("pub:")] == [
            fprs["pinned"]
        ]
        assert _offered(lab, files[name], "intruder", f"raw{sorted(armor.VARIANTS).index(name)}"), name


@pytest.mark.parametrize("name", sorted(armor.VARIANTS))
def test_the_installed_key_is_exactly_the_pinned_key_as_sqv_reads_it(lab, on_robot, name):
    fprs, files = on_robot
    label = f"v{sorted(armor.VARIANTS).index(name)}"
    dest = f"{WORK}/{label}/keyrings/docker.asc"
    script = aptrepo.key_script(docker_repo(f"file://{files[name]}", dest, fprs["pinned"]))
    code, output = lab.sh(HOST, ["sh", "-c", script])
    assert code == 0, output
    assert not _offered(lab, dest, "intruder", label), f"sqv trusts the key hidden {name}"
    assert _offered(lab, dest, "pinned", label)
    probe = lab.ok(HOST, ["sh", "-c", aptrepo.key_probe(dest, fprs["pinned"])])
    assert aptrepo.installed_key(probe) == aptrepo.InstalledKey((fprs["pinned"],), canonical=True)
    # the same file planted as it was downloaded: not current
    planted = lab.ok(HOST, ["sh", "-c", aptrepo.key_probe(files[name], fprs["pinned"])])
    assert not aptrepo.installed_key(planted).canonical
