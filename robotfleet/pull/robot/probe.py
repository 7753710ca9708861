"""Whether the releases branch is still the commit the last completed fetch
checked out: an idle check asks only that, and fetches nothing.

The last fetch that got as far as a complete checkout leaves a memo in the
agent's repository (``.git/robot-pull-fetched.json``: the remote, the branch,
the commit, how the remote answered, and a static remote's validators); a
fetch removes it before it starts, so a memo always names what the work
tree holds.  Then an idle check is one exchange:

- over HTTPS, one request from this process (no git, no curl): to a static
  copy a conditional GET of ``info/refs`` (If-None-Match / If-Modified-Since:
  304, nothing changed), to git's smart HTTP one protocol-v2 ``ls-refs``
  POST for the one branch (robotfleet/pull/robot/transport.py asks
  ``git ls-remote`` the same over SSH);
- an answer naming the memo's commit: the check goes on with that checkout;
  anything else (another commit, an error, a redirect, a proxy in the
  environment, credentials in the URL): the full fetch, as before.

What a server's answer can do is what serving the old branch could: a
server that keeps answering 304 freezes the robot on its last release, which
TUF's timestamp expiry catches, as it does a replayed branch (the agent
verifies the same metadata at each check).  The server's certificate is checked
as git checks it (``remote-ca.pem``, else the system's CAs).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

from robotfleet import atomicfile

MEMO = "robot-pull-fetched.json"
ANSWER_MAX = 1 << 16  # an ls-refs answer for one branch is one line
INFO_REFS_MAX = 32 << 20  # a static copy's info/refs lists every ref (reports too: ~64 bytes each)
_PROXIES = ("https_proxy", "HTTPS_PROXY", "all_proxy", "ALL_PROXY")
STABLE_AFTER = 60  # seconds between a Last-Modified and the Date it is trusted at


@dataclass
class Answer:
    """What one probe found: the branch's commit (None: unknown, fetch), the
    static copy's new validators, and its cost; over SSH, why it failed
    (``error``: then the fetch fails with it, robotfleet/pull/robot/remote_git.py)
    and the key the server accepted."""

    commit: str | None
    validators: dict = field(default_factory=dict)
    sent: int = 0
    received: int = 0
    error: str | None = None
    accepted: str | None = None


def memo_path(repo) -> str:
    return os.path.join(repo, ".git", MEMO)


def read_memo(repo, url: str, branch: str) -> dict | None:
    """The memo of the last completed fetch of ``branch`` from ``url``, or None."""
    try:
        with open(memo_path(repo)) as file:
            memo = json.load(file)
    except (OSError, ValueError):
        return None
    if not isinstance(memo, dict) or memo.get("url") != url or memo.get("branch") != branch:
        return None
    commit = memo.get("commit")
    if not isinstance(commit, str) or len(commit) not in (40, 64) or not _hex(commit):
        return None
    return memo


def write_memo(repo, url: str, branch: str, commit: str, kind: str, validators: dict | None = None) -> None:
    memo = {"url": url, "branch": branch, "commit": commit, "kind": kind, "validators": validators or {}}
    atomicfile.write(memo_path(repo), json.dumps(memo, sort_keys=True) + "\n")


def forget(repo) -> None:
    try:
        os.unlink(memo_path(repo))
    except FileNotFoundError:
        pass


def _hex(text: str) -> bool:
    return all(c in "0123456789abcdef" for c in text)


def commit_of(listing: bytes, ref: str) -> str | None:
    """The object id ``listing`` ("<oid> <ref>" or "<oid>\\t<ref>" lines, as
    ls-remote, ls-refs and info/refs give them) names for ``ref``."""
    for line in listing.splitlines():
        parts = line.split(maxsplit=2)
        if len(parts) >= 2 and parts[1].decode(errors="replace") == ref:
            oid = parts[0].decode(errors="replace")
            return oid if len(oid) in (40, 64) and _hex(oid) else None
    return None


def pkt_lines(data: bytes) -> bytes | None:
    """The payload of git's pkt-line stream ``data`` up to its flush, lines
    joined; None when it is not one."""
    out, at = [], 0
    while at + 4 <= len(data):
        try:
            size = int(data[at : at + 4], 16)
        except ValueError:
            return None
        if size == 0:
            return b"".join(out)
        if size < 4 or at + size > len(data):
            return None
        out.append(data[at + 4 : at + size])
        at += size
    return None


def pkt(line: str) -> bytes:
    return f"{len(line) + 4:04x}{line}".encode()


def ls_refs_request(ref: str) -> bytes:
    """A protocol-v2 ``ls-refs`` for the one ref (git's smart HTTP, stateless)."""
    return pkt("command=ls-refs\n") + b"0001" + pkt(f"ref-prefix {ref}\n") + b"0000"


def https(url: str, branch: str, memo: dict, ca: str | None, timeout: float, silent: float = 60) -> Answer | None:
    """Ask the HTTPS remote ``url`` what ``branch`` is now, the way ``memo``
    says it answered last, within ``timeout``, given up after ``silent``
    seconds without a byte (robotfleet/pull/robot/https_request.py); None
    when this remote cannot be probed here (a proxy, credentials in the URL:
    git's own fetch knows how).  A port that is no number fails the probe."""
    from urllib import parse

    parts = parse.urlsplit(url)
    if parts.scheme != "https" or parts.username or parts.password or any(os.environ.get(p) for p in _PROXIES):
        return None
    from robotfleet.pull.robot import https_request

    try:
        port = parts.port or 443
    except ValueError:
        return Answer(None)
    base, ref = parts.path.rstrip("/"), f"refs/heads/{branch}"
    host = f"Host: {parts.netloc}\r\nUser-Agent: robot-pull\r\n"
    if memo.get("kind") == "static":
        validators = memo.get("validators") or {}
        head = f"GET {base}/info/refs HTTP/1.1\r\n{host}" + "".join(
            f"{name}: {validators[key]}\r\n"
            for name, key in (("If-None-Match", "etag"), ("If-Modified-Since", "last_modified"))
            if isinstance(validators.get(key), str) and validators[key].isprintable()
        )
        body, limit = b"", INFO_REFS_MAX
    else:
        body, limit = ls_refs_request(ref), ANSWER_MAX
        head = (
            f"POST {base}/git-upload-pack HTTP/1.1\r\n{host}Content-Type: application/x-git-upload-pack-request"
            f"\r\nGit-Protocol: version=2\r\nContent-Length: {len(body)}\r\n"
        )
    try:
        answer = https_request.request(parts.hostname, port, head.encode(), body, ca, timeout, limit, silent)
    except (OSError, ValueError):  # ssl.SSLError and TimeoutError are OSErrors
        return Answer(None)
    if memo.get("kind") == "static":
        found = _static(answer, memo, ref)
    else:
        listing = pkt_lines(answer.body) if answer.status == 200 else None
        found = Answer(commit_of(listing, ref) if listing is not None else None)
    found.sent, found.received = answer.sent, answer.received
    return found


def _static(answer, memo: dict, ref: str) -> Answer:
    """A static copy's answer to the conditional GET of info/refs."""
    if answer.status == 304:
        return Answer(memo["commit"], memo.get("validators") or {})
    if answer.status != 200:
        return Answer(None)
    return Answer(commit_of(answer.body, ref), validators_of(answer.headers))


def validators_of(headers: dict) -> dict:
    """The validators of a static copy's answer (``headers``: lower-case
    names) that may stand for its content.  A file's Last-Modified (and the
    ETag servers make of it, e.g. nginx's mtime and size) has one-second
    steps: two publishes in one second could share them.  So, as RFC 9110
    8.8.2.2 says, they stand only when Last-Modified is at least a minute
    before the answer's Date; else none is kept (the next check asks
    unconditionally)."""
    from email.utils import parsedate_to_datetime

    etag, modified, date = (headers.get(name) for name in ("etag", "last-modified", "date"))
    if modified:
        try:
            if (parsedate_to_datetime(date) - parsedate_to_datetime(modified)).total_seconds() < STABLE_AFTER:
                return {}
        except (TypeError, ValueError):
            return {}
    return {k: v for k, v in (("etag", etag), ("last_modified", modified)) if v}
