"""Debian packages installed in a lab image's build (on the host image): no
daemon a package brings may start inside the build (policy-rc.d)."""

from __future__ import annotations


def script(packages) -> str:
    """Shell lines that install ``packages``, apt-get update first."""
    return f"""# No daemons may start inside the build.
printf '#!/bin/sh\\nexit 101\\n' > /usr/sbin/policy-rc.d
chmod 0755 /usr/sbin/policy-rc.d
apt-get update
DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends {" ".join(packages)}
rm /usr/sbin/policy-rc.d
"""
