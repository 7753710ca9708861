"""The robot's own key for the fleet remote (agent_files.KEY), made on the robot:
the one shell both the pull role (over SSH) and a first-boot bundle's
script (at boot) run."""

from __future__ import annotations

from robotfleet.pull.protocol import agent_files


def keygen_script(comment: str) -> str:
    """Make the key pair in a private directory beside its place, then rename
    it into place (a cut leaves no half key); the directory goes on failure.
    ``comment``: one shell word, quoted by the caller (it may expand)."""
    return f"""(
set -e
umask 077
tmp=$(mktemp -d {agent_files.ETC}/.key.XXXXXX); trap 'rm -rf "$tmp"' EXIT
ssh-keygen -q -t ed25519 -N '' -C {comment} -f "$tmp/key"
mv -T "$tmp/key.pub" {agent_files.KEY}.pub
mv -T "$tmp/key" {agent_files.KEY}
)
"""
