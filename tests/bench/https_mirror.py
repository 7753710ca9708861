"""A static HTTPS copy of the fleet remote served by the lab's git server
itself, for ``git_load.py --checks https``: the layout docs/explanations/pull.md
recommends at 10,000 robots (idle checks from a static copy, reports pushed
over SSH to gitolite), with the web server on the git server, so that its
CPU is counted with the rest.

- nginx from Debian's archive, installed at the bench's first use on that
  server (the lab's image has none; the test command never needs it);
- TLS 1.3 only, a CA of the bench's own (tests/integration/httpsgit.py
  ``make_ca``), session tickets off: the robots' probe opens one connection
  per check and cannot use a ticket (docs/guides/pull.md, Releases over HTTPS);
- the copy as docs/guides/pull-from-nothing.md step 9 makes it: a mirror
  clone of the fleet repository after ``git update-server-info`` (git's
  dumb protocol), under /srv/www.

It is reached on the lab's own docker network (the container's address
there), never through a published port.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tests.lab import apt_install

CONF = "/etc/nginx/conf.d/robotfleet-mirror.conf"
CERT, KEY = "/etc/robot-lab/mirror.pem", "/etc/robot-lab/mirror.key"
ROOT = "/srv/www"
SITE = """server {{
    listen {address}:443 ssl;
    ssl_certificate {cert};
    ssl_certificate_key {key};
    ssl_protocols TLSv1.3;
    ssl_session_tickets off;
    access_log off;
    root {root};
    location / {{ try_files $uri =404; }}
}}
"""


def address(container: str) -> str:
    """The container's address on its (one) lab network."""
    found = subprocess.run(
        ["docker", "inspect", "-f", "{{json .NetworkSettings.Networks}}", container],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return next(iter(json.loads(found).values()))["IPAddress"]


def ensure(server, repositories: str) -> tuple[str, Path]:
    """nginx on ``server`` (gitolite_fleet.Server) serving a fresh static copy
    of its fleet repository: (the copy's URL, the CA to trust)."""
    from tests.integration.httpsgit import make_ca

    container = server.git["container"]
    ip = address(container)
    ca, cert, key = make_ca(server.base / "mirror-tls", ip)
    server.sh(f"command -v nginx >/dev/null || {{ {apt_install.script(['nginx'])} }}", user="root")
    for path, source in ((CERT, cert), (KEY, key)):
        subprocess.run(["docker", "cp", str(source), f"{container}:{path}"], check=True, capture_output=True)
    site = SITE.format(address=ip, cert=CERT, key=KEY, root=ROOT)
    repo = server.git["repo"]
    server.sh(
        f"set -e; chmod 0644 {CERT}; chown www-data {KEY}; chmod 0600 {KEY}; cat > {CONF}; "
        f"rm -rf {ROOT}/{repo}.git; install -d -o gitolite3 -m 0755 {ROOT}",
        stdin=site.encode(),
        user="root",
    )
    server.sh(  # as the repositories' owner: git refuses to read another user's
        f"set -e; git clone -q --mirror {repositories}/{repo}.git {ROOT}/{repo}.git; "
        f"git -C {ROOT}/{repo}.git update-server-info; chmod -R a+rX {ROOT}/{repo}.git"
    )
    server.sh("nginx -t -q && systemctl restart nginx.service", user="root")
    return f"https://{ip}/{repo}.git", ca
