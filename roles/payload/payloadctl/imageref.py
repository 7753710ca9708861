"""Docker image references: the distribution spec's grammar and the
pinning policy (pure; the deploy side checks the fleet file with it, the
robot side pins and compares references with it)."""

import re
from typing import NamedTuple, Optional

_COMPONENT = r"[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*"
_DOMAIN = r"(?:[A-Za-z0-9](?:[A-Za-z0-9-]*[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]*[A-Za-z0-9])?)*(?::[0-9]+)?)"
# The distribution spec's grammar is ASCII: its \w means [A-Za-z0-9_], where
# Python's \w would also take Unicode letters and digits (look-alikes).
_TAG = r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}"
_REFERENCE = re.compile(
    rf"(?:(?P<domain>{_DOMAIN})/)?(?P<path>{_COMPONENT}(?:/{_COMPONENT})*)"
    rf"(?::(?P<tag>{_TAG}))?(?:@(?P<digest>sha256:[a-f0-9]{{64}}))?",
    re.ASCII,
)
NAME_MAX = 255  # the spec's limit on the repository name, registry included
_DIGEST = r"sha256:[a-f0-9]{64}"
# The same grammar for JSON Schema (editors): no group names, and the name's
# limit as a lookahead (what precedes an optional tag and digest is at most
# NAME_MAX characters).
JSON_PATTERN = (
    rf"^(?=.{{1,{NAME_MAX}}}(?::{_TAG})?(?:@{_DIGEST})?$)"
    rf"(?:{_DOMAIN}/)?{_COMPONENT}(?:/{_COMPONENT})*(?::{_TAG})?(?:@{_DIGEST})?$"
)


def _shown(text) -> str:
    shown = repr(text)
    return shown if len(shown) <= 80 else shown[:75] + "...'"


class ImageRef(NamedTuple):
    repository: str  # including the registry, if any
    tag: Optional[str]
    digest: Optional[str]

    @property
    def registry(self) -> str:
        first, _, rest = self.repository.partition("/")
        if rest and ("." in first or ":" in first or first == "localhost"):
            return first
        return "docker.io"

    def __str__(self) -> str:
        text = self.repository
        if self.tag:
            text += f":{self.tag}"
        if self.digest:
            text += f"@{self.digest}"
        return text


def parse(text: str) -> ImageRef:
    match = _REFERENCE.fullmatch(text) if isinstance(text, str) else None
    if not match:
        raise ValueError(f"{_shown(text)} is not a valid image reference")
    domain = match.group("domain")
    path = match.group("path")
    # "host:5000/x" is a registry; "name:tag" without a slash is a tag.
    if domain and not ("." in domain or ":" in domain or domain == "localhost"):
        path = f"{domain}/{path}"
        domain = None
    repository = f"{domain}/{path}" if domain else path
    if len(repository) > NAME_MAX:
        raise ValueError(f"{_shown(text)} is not a valid image reference (name longer than {NAME_MAX} characters)")
    return ImageRef(repository, match.group("tag"), match.group("digest"))


def repository(text: str) -> str:
    """The repository of a reference (registry included), or the text itself
    where it is not a valid reference (an image id)."""
    try:
        return parse(text).repository
    except ValueError:
        return text


def pinning_problem(text: str, allow_latest: bool) -> Optional[str]:
    """Why ``text`` is not an acceptable payload image, or None."""
    try:
        ref = parse(text)
    except ValueError as error:
        return str(error)
    if ref.digest:
        return None
    if not ref.tag:
        return f"{_shown(text)} has no tag or digest; pin a version (e.g. {text}:1.4.2 or @sha256:...)"
    if ref.tag == "latest" and not allow_latest:
        return (
            f"{_shown(text)} uses the moving tag 'latest'; pin a version or digest (or set payload_allow_latest: true)"
        )
    return None
