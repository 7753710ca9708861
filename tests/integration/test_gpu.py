"""The gpu role's key download (tests/unit/test_gpu.py plans the rest): the
real script against real keys, served from file:// by curl."""

import pytest

from robotfleet.host import aptrepo
from tests import armor
from tests.fixtures import sh


@pytest.mark.parametrize("case", ["pinned", "other", "pinned+other"])
def test_key_download_accepts_exactly_the_pinned_primary_key(tmp_path, case):
    home = tmp_path / "gnupg"
    pinned = armor.new_key(home, "Pinned <pinned@example.invalid>")
    other = armor.new_key(home, "Other <other@example.invalid>")
    exported = {"pinned": [pinned], "other": [other], "pinned+other": [pinned, other]}[case]
    key = tmp_path / "gpgkey"
    key.write_bytes(armor.gpg(home, "--armor", "--export", *exported).stdout)
    dest = tmp_path / "keyrings" / "nvidia.asc"
    script = aptrepo.key_script(
        aptrepo.Repository(
            "NVIDIA",
            f"file://{key}",
            str(dest),
            pinned,
            "gpu_apt_key_fingerprint",
            "nvidia-container-toolkit",
            "",
            "gpu_key_fingerprints",
        )
    )
    proc = sh(script)
    if case == "pinned":
        assert proc.returncode == 0, proc.stderr
        assert dest.read_bytes() == key.read_bytes()
        probe = sh(aptrepo.key_probe(str(dest), pinned))
        assert aptrepo.installed_key(probe.stdout) == aptrepo.InstalledKey((pinned,), canonical=True)
    else:
        assert proc.returncode == 1
        assert "gpu_apt_key_fingerprint" in proc.stderr and "key not installed" in proc.stderr
        assert not dest.exists() and list(dest.parent.iterdir()) == []  # nothing left behind
