"""Which Debian archive the lab downloads from (mmdebstrap, the Docker CE
mirror's source packages).

Robot networks often sit behind their own Debian mirror or proxy, so the
default is the archive this machine's apt already uses: the first Debian
main-archive entry in /etc/apt/sources.list, then sources.list.d/*.list and
*.sources (deb822) in name order, as apt reads them.  ``ROBOT_LAB_DEBIAN_URL``
overrides it; with neither, deb.debian.org.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

ENV_VAR = "ROBOT_LAB_DEBIAN_URL"
DEFAULT_URL = "http://deb.debian.org/debian"
APT_DIR = Path("/etc/apt")

# Debian release names (and aliases) whose main archive can serve trixie:
# a Debian machine's own sources name one of these; an Ubuntu machine's do not.
DEBIAN_SUITES = {
    "buster",
    "bullseye",
    "bookworm",
    "trixie",
    "forky",
    "duke",
    "sid",
    "oldoldstable",
    "oldstable",
    "stable",
    "testing",
    "unstable",
}


class ArchiveError(Exception):
    pass


@dataclass(frozen=True)
class Source:
    type: str  # "deb" or "deb-src"
    uri: str
    suite: str
    components: tuple[str, ...]
    origin: str  # "file:line" for messages


def parse_one_line_style(text: str, origin: str = "sources.list") -> list[Source]:
    """``deb [option=value ...] URI SUITE COMPONENT...`` lines."""
    sources = []
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        line = re.sub(r"\[[^\]]*\]", " ", line, count=1)  # options
        words = line.split()
        if len(words) < 3 or words[0] not in ("deb", "deb-src"):
            continue
        sources.append(Source(words[0], words[1], words[2], tuple(words[3:]), f"{origin}:{number}"))
    return sources


def parse_deb822_style(text: str, origin: str = "x.sources") -> list[Source]:
    """deb822 stanzas (``Types:``, ``URIs:``, ``Suites:``, ``Components:``,
    ``Enabled:``), blank-line separated; one Source per type, URI and suite."""
    sources = []
    for start, stanza in _stanzas(text):
        fields = {key.lower(): value for key, value in stanza.items()}
        if fields.get("enabled", "yes").strip().lower() == "no":
            continue
        for kind in fields.get("types", "").split():
            for uri in fields.get("uris", "").split():
                for suite in fields.get("suites", "").split():
                    sources.append(
                        Source(kind, uri, suite, tuple(fields.get("components", "").split()), f"{origin}:{start}")
                    )
    return sources


def _stanzas(text: str):
    stanza: dict[str, str] = {}
    start = key = None
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("#"):
            continue
        if not line.strip():
            if stanza:
                yield start, stanza
            stanza, start, key = {}, None, None
            continue
        if line[0] in " \t" and key:
            stanza[key] += " " + line.strip()  # continuation line
            continue
        key, sep, value = line.partition(":")
        if not sep:
            key = None
            continue
        key = key.strip()
        stanza[key] = value.strip()
        start = start or number
    if stanza:
        yield start, stanza


def machine_sources(apt_dir: Path = APT_DIR) -> list[Source]:
    """Every apt source of this machine, in the order apt reads them."""
    sources = []
    main = apt_dir / "sources.list"
    if main.is_file():
        sources += parse_one_line_style(main.read_text(errors="replace"), str(main))
    parts = apt_dir / "sources.list.d"
    if parts.is_dir():
        for path in sorted(parts.iterdir()):
            if path.suffix == ".list" and path.is_file():
                sources += parse_one_line_style(path.read_text(errors="replace"), str(path))
            elif path.suffix == ".sources" and path.is_file():
                sources += parse_deb822_style(path.read_text(errors="replace"), str(path))
    return sources


def is_debian_main_archive(source: Source) -> bool:
    suite = source.suite.split("/")[0]
    return (
        source.type == "deb"
        and source.uri.startswith(("http://", "https://"))
        and suite in DEBIAN_SUITES  # not -security, -updates, -backports, nor other distributions
        and "main" in source.components
    )


def debian_archive_url(apt_dir: Path = APT_DIR, environ=os.environ) -> str:
    """The Debian archive URL the lab uses (no trailing slash)."""
    override = environ.get(ENV_VAR, "").strip()
    if override:
        if not override.startswith(("http://", "https://")):
            raise ArchiveError(f"{ENV_VAR}={override!r}: expected an http:// or https:// URL of a Debian archive")
        return override.rstrip("/")
    for source in machine_sources(apt_dir):
        if is_debian_main_archive(source):
            return source.uri.rstrip("/")
    return DEFAULT_URL
