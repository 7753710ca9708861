"""What the robot's ssh offers the git server (robotfleet/pull/robot/ssh_options.py):
the pinned keys' algorithms only, or ssh's own when a line is not a plain pinned key."""

from __future__ import annotations

from robotfleet.pull.robot import ssh_options

ED, RSA = "robotfleet-remote ssh-ed25519 AAAAC3Nz", "robotfleet-remote ssh-rsa AAAAB3Nz"


def test_the_host_key_algorithms_are_the_pinned_keys_own():
    assert ssh_options.host_key_algorithms(f"{ED}\n") == "ssh-ed25519"
    assert ssh_options.host_key_algorithms(f"# pinned\n{ED}\n{RSA}\n{ED}\n") == "ssh-ed25519,rsa-sha2-512,rsa-sha2-256"


def test_anything_but_plain_pinned_keys_leaves_the_choice_to_ssh():
    dss = "robotfleet-remote ssh-dss AAAAB3"
    for text in ("", f"@cert-authority * {ED[18:]}\n", f"{ED}\n{dss}\n", "robotfleet-remote\n"):
        assert ssh_options.host_key_algorithms(text) is None, text


def test_the_options_offer_aead_ciphers_and_the_pinned_algorithms(tmp_path):
    pinned = tmp_path / "known_hosts"
    pinned.write_text(f"{ED}\n")
    assert ssh_options.options(str(pinned)) == [
        "-o",
        f"Ciphers={ssh_options.CIPHERS}",
        "-o",
        f"MACs={ssh_options.MACS}",
        "-o",
        "HostKeyAlgorithms=ssh-ed25519",
    ]
    assert "HostKeyAlgorithms" not in " ".join(ssh_options.options(str(tmp_path / "absent")))
