"""Issue 17 item 1: the key pin is judged by apt's own reading of the
installed key file, not only by gpg's.

gpg and apt 2.6 (Debian 12; apt-key's awk+base64 dearmoring before gpgv)
parse an armored file differently: each variant in ``tests.armor`` hides a
second key block that ``gpg --show-keys`` does not list.  Each test builds a
tiny local apt repository (file://) whose InRelease is signed by that hidden
key, runs the real ``apt-get update`` against the key file as ``Signed-By``
with a private apt configuration (the machine's own apt state is not
touched), and asks ``apt-cache policy`` whether apt now offers the fake
docker-ce.  tests/e2e/test_key_pin_sqv.py does the same with Debian 13's
apt and sqv on a lab host.
"""

from __future__ import annotations

import shutil
import subprocess

import pytest

from robotfleet.host import aptrepo
from robotfleet.host.snapshot import FileState, Snapshot
from tests import armor
from tests.unit.harness import docker_repo

pytestmark = pytest.mark.skipif(shutil.which("apt-get") is None, reason="needs apt (Debian)")
ALL = sorted(armor.VARIANTS)


@pytest.fixture(scope="module")
def signers(tmp_path_factory):
    home = tmp_path_factory.mktemp("signers")
    home.chmod(0o700)
    return (home, *armor.signers(home))


@pytest.fixture(scope="module")
def repos(signers, tmp_path_factory):
    home, fprs, _ = signers
    base = tmp_path_factory.mktemp("repos")
    for name, fpr in fprs.items():
        armor.repository(home, fpr, base / name)
    return {name: str(base / name) for name in fprs}


def apt_offers_the_repository(key_file, repo: str, tmp_path) -> bool:
    """Whether apt, with ``key_file`` as Signed-By, accepts ``repo``'s
    InRelease (then apt-cache policy offers its fake docker-ce)."""
    work = tmp_path / f"apt-{len(list(tmp_path.glob('apt-*')))}"
    proc = subprocess.run(
        ["sh", "-c", armor.apt_check_script(str(key_file), repo, str(work))],
        capture_output=True,
        text=True,
        timeout=180,
    )
    return armor.parse_check(proc.stdout)


def _variant(signers, name: str) -> bytes:
    return armor.variant(name, signers[2])


def _listed_by_gpg(path, tmp_path) -> list[str]:
    """The primary keys ``gpg --show-keys`` lists in ``path`` (what the pin checked before)."""
    home = tmp_path / "gnupg-show"
    home.mkdir(mode=0o700)
    listing = armor.gpg(home, "--show-keys", "--with-colons", str(path), text=True).stdout.splitlines()
    return [listing[n + 1].split(":")[9] for n, line in enumerate(listing) if line.startswith("pub:")]


def test_the_repository_check_itself_can_tell(signers, repos, tmp_path):
    """The pinned key alone: apt takes the pinned key's Release, not the intruder's."""
    _, _, armored = signers
    key = tmp_path / "pinned.asc"
    key.write_text(armored["pinned"])
    assert apt_offers_the_repository(key, repos["pinned"], tmp_path)
    assert not apt_offers_the_repository(key, repos["intruder"], tmp_path)


@pytest.mark.parametrize("variant", ALL)
def test_gpg_lists_only_the_pinned_key_while_apt_trusts_the_hidden_one(signers, repos, tmp_path, variant):
    """The blind spot itself (gpg 2.2 and apt 2.6 as on Debian 12; the
    indented BEGIN line is sqv's, apt 2.6 skips it): if this stops holding,
    the variant no longer tests what it says."""
    _, fprs, _ = signers
    planted = tmp_path / "docker.asc"
    planted.write_bytes(_variant(signers, variant))
    assert _listed_by_gpg(planted, tmp_path) == [fprs["pinned"]]
    assert apt_offers_the_repository(planted, repos["intruder"], tmp_path) == (variant in armor.APT26_TRUSTS_HIDDEN)


@pytest.mark.parametrize("variant", ALL)
def test_a_download_with_a_hidden_key_installs_only_the_pinned_key_as_apt_reads_it(signers, repos, tmp_path, variant):
    _, fprs, _ = signers
    served = tmp_path / "gpg"
    served.write_bytes(_variant(signers, variant))
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    proc = subprocess.run(
        ["sh", "-c", aptrepo.key_script(docker_repo(f"file://{served}", str(dest), fprs["pinned"]))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert not apt_offers_the_repository(dest, repos["intruder"], tmp_path), f"apt trusts the key hidden {variant}"
    assert apt_offers_the_repository(dest, repos["pinned"], tmp_path)
    assert sorted(p.name for p in dest.parent.iterdir()) == ["docker.asc"]
    assert oct(dest.stat().st_mode)[-3:] == "644"


def _key_probe(path, fingerprint):
    return subprocess.run(
        ["sh", "-c", aptrepo.key_probe(str(path), fingerprint)], capture_output=True, text=True
    ).stdout


@pytest.mark.parametrize("variant", ALL)
def test_a_planted_key_file_with_a_hidden_key_is_not_current_and_is_replaced(signers, repos, tmp_path, variant):
    _, fprs, armored = signers
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(_variant(signers, variant))
    dest.chmod(0o644)
    repo = docker_repo("", str(dest), fprs["pinned"])
    snap = Snapshot(
        files={str(dest): FileState("file", "a" * 64, "644", "root", "root")},
        probes={"docker_key_fingerprints": _key_probe(dest, fprs["pinned"])},
    )
    assert not aptrepo.key_is_current(repo, snap)
    served = tmp_path / "gpg"
    served.write_text(armored["pinned"])
    repo = docker_repo(f"file://{served}", str(dest), fprs["pinned"])
    proc = subprocess.run(["sh", "-c", aptrepo.key_script(repo)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert not apt_offers_the_repository(dest, repos["intruder"], tmp_path)
    assert apt_offers_the_repository(dest, repos["pinned"], tmp_path)


@pytest.mark.parametrize("variant", ALL)
def test_a_planted_key_file_is_removed_when_the_download_fails(signers, repos, tmp_path, variant):
    """Fail closed: apt must not go on trusting the hidden key while the key URL is down."""
    _, fprs, _ = signers
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(_variant(signers, variant))
    repo = docker_repo(f"file://{tmp_path}/nothing-here", str(dest), fprs["pinned"])
    proc = subprocess.run(["sh", "-c", aptrepo.key_script(repo)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "cannot download the Docker apt key" in proc.stderr
    assert not apt_offers_the_repository(dest, repos["intruder"], tmp_path)
    assert list(dest.parent.iterdir()) == []


def _run(repo) -> subprocess.CompletedProcess:
    return subprocess.run(["sh", "-c", aptrepo.key_script(repo)], capture_output=True, text=True, timeout=60)


def test_nvidias_key_as_the_gpu_role_declares_it_goes_the_same_way(signers, repos, tmp_path):
    """The gpu role's own Repository (NVIDIA's key), pointed at a local download with a hidden key."""
    from roles import gpu
    from tests.unit.harness import merged

    _, fprs, _ = signers
    served = tmp_path / "gpgkey"
    served.write_bytes(_variant(signers, "text after the BEGIN line"))
    dest = tmp_path / "keyrings" / "nvidia-container-toolkit.asc"
    data = merged(
        "robots",
        {
            "gpu_vendor": "nvidia",
            "gpu_apt_key_url": f"file://{served}",
            "gpu_apt_key_path": str(dest),
            "gpu_apt_key_fingerprint": fprs["pinned"],
        },
    )
    repo = gpu.repository(data, "amd64")
    assert (repo.what, repo.fingerprint, repo.key_path) == ("NVIDIA", fprs["pinned"], str(dest))
    proc = _run(repo)
    assert proc.returncode == 0, proc.stderr
    assert not apt_offers_the_repository(dest, repos["intruder"], tmp_path)
    assert apt_offers_the_repository(dest, repos["pinned"], tmp_path)
    snap = Snapshot(
        files={str(dest): FileState("file", "a" * 64, "644", "root", "root")},
        probes={gpu.KEY_PROBE: _key_probe(dest, fprs["pinned"])},
    )
    assert aptrepo.key_is_current(repo, snap)


def test_a_key_path_not_ending_in_asc_gets_the_binary_export_and_apt_reads_it(signers, repos, tmp_path):
    _, fprs, _ = signers
    served = tmp_path / "gpg"
    served.write_bytes(_variant(signers, "unknown armor label"))
    dest = tmp_path / "keyrings" / "docker.gpg"
    repo = docker_repo(f"file://{served}", str(dest), fprs["pinned"])
    assert _run(repo).returncode == 0
    assert not dest.read_bytes().startswith(b"-----")  # binary OpenPGP packets
    assert not apt_offers_the_repository(dest, repos["intruder"], tmp_path)
    assert apt_offers_the_repository(dest, repos["pinned"], tmp_path)
    assert aptrepo.installed_key(_key_probe(dest, fprs["pinned"])) == aptrepo.InstalledKey((fprs["pinned"],), True)
    # the armored form at a .gpg path is not what the script installs: replaced
    dest.write_bytes(signers[2]["pinned"].encode())
    assert not aptrepo.installed_key(_key_probe(dest, fprs["pinned"])).canonical


def test_the_sha256_pins_the_download_and_the_installed_export_is_still_current(signers, tmp_path):
    """With both pins the sha256 is the downloaded file's; the installed file
    is gpg's export (other bytes), judged by the probe, not by that sha256."""
    _, fprs, _ = signers
    served = tmp_path / "gpg"
    served.write_bytes(_variant(signers, "PGP MESSAGE label"))
    digest = subprocess.run(["sha256sum", str(served)], capture_output=True, text=True, check=True).stdout.split()[0]
    dest = tmp_path / "keyrings" / "docker.asc"
    wrong = _run(docker_repo(f"file://{served}", str(dest), fprs["pinned"], "0" * 64))
    assert wrong.returncode == 1 and "does not match docker_apt_key_sha256" in wrong.stderr
    assert list(dest.parent.iterdir()) == []
    repo = docker_repo(f"file://{served}", str(dest), fprs["pinned"], digest)
    assert _run(repo).returncode == 0
    installed = subprocess.run(["sha256sum", str(dest)], capture_output=True, text=True).stdout.split()[0]
    assert installed != digest
    snap = Snapshot(
        files={str(dest): FileState("file", installed, "644", "root", "root")},
        probes={repo.probe: _key_probe(dest, fprs["pinned"])},
    )
    assert aptrepo.key_is_current(repo, snap)


def test_a_planted_key_file_is_named_in_one_line_when_removed(signers, tmp_path):
    _, fprs, _ = signers
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()
    dest.write_bytes(_variant(signers, "inside the block after its CRC line"))
    proc = _run(docker_repo(f"file://{tmp_path}/nothing-here", str(dest), fprs["pinned"]))
    lines = proc.stderr.splitlines()  # curl's own error line comes between
    assert lines[0] == (
        f"{dest} is not exactly the pinned key as gpg exports it (docker_apt_key_fingerprint {fprs['pinned']}); removed"
    )
    assert lines[-1] == f"cannot download the Docker apt key from file://{tmp_path}/nothing-here"


def test_a_download_gpg_cannot_read_is_refused_in_one_line(signers, repos, tmp_path):
    """A wrong CRC on the second block: gpg reads nothing at all, apt 2.6 (and sqv) trust both keys."""
    _, fprs, armored = signers
    served = tmp_path / "gpg"
    served.write_bytes(armor.bad_crc(armored))
    assert apt_offers_the_repository(served, repos["intruder"], tmp_path)
    dest = tmp_path / "keyrings" / "docker.asc"
    proc = _run(docker_repo(f"file://{served}", str(dest), fprs["pinned"]))
    assert proc.returncode == 1
    assert proc.stderr.splitlines() == [
        f"Docker apt key from file://{served}: fingerprint (none: no key gpg can read) does not match "
        f"docker_apt_key_fingerprint {fprs['pinned']}; key not installed"
    ]
    assert list(dest.parent.iterdir()) == []


def test_the_probe_reads_the_same_through_the_hosts_one_snapshot_command(signers, tmp_path):
    """Quoted into the snapshot script (timeout, sh -c, base64) as deploy.py
    reads it: a converged key file is current, a planted one is not."""
    from robotfleet.host.snapshot import HostSnapshot

    _, fprs, armored = signers
    good, planted = tmp_path / "good.asc", tmp_path / "planted.asc"
    served = tmp_path / "gpg"
    served.write_text(armored["pinned"])
    assert _run(docker_repo(f"file://{served}", str(good), fprs["pinned"])).returncode == 0
    planted.write_bytes(_variant(signers, "PGP MESSAGE label"))
    planted.chmod(0o644)
    for path, current in ((good, True), (planted, False)):
        repo = docker_repo("", str(path), fprs["pinned"])
        fact = HostSnapshot()
        script = fact.command(files=[str(path)], probes={repo.probe: aptrepo.key_probe(str(path), fprs["pinned"])})
        out = subprocess.run(["sh", "-c", script], capture_output=True, text=True, check=True, timeout=120)
        assert aptrepo.key_is_current(repo, fact.process(out.stdout.splitlines())) is current, path.name


def test_a_mistyped_pin_leaves_the_robots_working_key_in_place(signers, tmp_path):
    """gpg's clean export of one key holds nothing hidden: a wrong pin
    refuses the download, and the key apt already uses stays (removing it
    would stop every apt update on the robot until the pin is fixed)."""
    _, fprs, armored = signers
    served = tmp_path / "gpg"
    served.write_text(armored["pinned"])
    dest = tmp_path / "keyrings" / "docker.asc"
    dest.parent.mkdir()

    def run(pin):
        return subprocess.run(
            ["sh", "-c", aptrepo.key_script(docker_repo(f"file://{served}", str(dest), pin))],
            capture_output=True,
            text=True,
            timeout=60,
        )

    assert run(fprs["pinned"]).returncode == 0
    good = dest.read_bytes()
    wrong = run("DEAD" * 10)
    assert wrong.returncode == 1 and f"does not match docker_apt_key_fingerprint {'DEAD' * 10}" in wrong.stderr
    assert "removed" not in wrong.stderr and dest.read_bytes() == good
