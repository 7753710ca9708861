"""A signed apt repository laid out like https://download.docker.com/linux.

Docker's repository is not reachable from the lab, so this builds a stand-in:
Debian 13 (trixie) packages repackaged under Docker's names, so that hosts
install a real engine and a real compose v2 through exactly the code path used
against Docker's repository (keyring at linux/debian/gpg, deb822 source with
Signed-By, suite trixie, component stable), for amd64 and arm64 (Debian's
own builds of each architecture, pool/stable/<arch>/, one Packages list per
architecture, as Docker lays its repository out).

Mapping (Docker name <- Debian trixie package):
    docker-ce              <- docker.io       (engine only: the CLI is split out in trixie)
    docker-ce-cli          <- docker-cli
    containerd.io          <- containerd + runc (Docker's containerd.io ships runc)
    docker-buildx-plugin   <- docker-buildx
    docker-compose-plugin  <- docker-compose  (minus /usr/bin/docker-compose, which
                                               Docker's plugin package does not ship)

Each repackaged package Conflicts/Replaces/Provides the Debian names it stands
for, so docker.io and docker-ce cannot coexist, like the real thing.

Sources are resolved once and pinned in the cache manifest; a cache hit needs no
network. ``build_mirror(out, refresh=True)`` re-resolves trixie and rebuilds
only if a source version changed.

CLI: python3 -m tests.lab.mirror [--refresh] [OUT_DIR]
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import gzip
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .debian_archive import ArchiveError, debian_archive_url

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUT_DIR = REPO_ROOT / ".lab" / "cache" / "docker-mirror"

DEBIAN_KEYRING = "/usr/share/keyrings/debian-archive-keyring.gpg"
SUITE = "trixie"
DEBIAN_RELEASE = "13"
COMPONENT = "stable"
ARCHES = ("amd64", "arm64")

KEY_UID = "Robot Lab Docker Mirror (lab only, not Docker) <docker-mirror@robot-lab.invalid>"
LAB_MAINTAINER = "Robot Lab Docker Mirror <docker-mirror@robot-lab.invalid>"


@dataclasses.dataclass(frozen=True)
class Rule:
    """How one Docker-named package is made from Debian packages."""

    name: str
    sources: tuple[str, ...]  # first one is primary: its control/scripts are kept
    epoch: str | None = None
    distro_suffix: bool = True  # "-1~debian.13~trixie" vs plain "-1" (containerd.io)
    add_depends: tuple[str, ...] = ()
    add_recommends: tuple[str, ...] = ()
    drop_relations: tuple[str, ...] = ()  # names dropped from Depends/Recommends/...
    drop_paths: tuple[str, ...] = ()
    add_symlinks: tuple[tuple[str, str], ...] = ()  # (path, target)


RULES: tuple[Rule, ...] = (
    # needrestart (restarts services after upgrades) and criu (pulls python3) are
    # Debian recommendations Docker's packages don't make: they would change what
    # a provisioned host looks like.
    # Debian installs dockerd in /usr/sbin, Docker in /usr/bin: both paths work
    # (e.g. for an ExecStart= override written against Docker's layout).
    Rule(
        "docker-ce",
        ("docker.io",),
        epoch="5",
        add_depends=("docker-ce-cli",),
        drop_relations=("needrestart",),
        add_symlinks=(("usr/bin/dockerd", "../sbin/dockerd"), ("usr/bin/docker-proxy", "../sbin/docker-proxy")),
    ),
    Rule("docker-ce-cli", ("docker-cli",), epoch="5", add_recommends=("docker-buildx-plugin", "docker-compose-plugin")),
    Rule("containerd.io", ("containerd", "runc"), distro_suffix=False, drop_relations=("criu",)),
    Rule("docker-buildx-plugin", ("docker-buildx",)),
    Rule("docker-compose-plugin", ("docker-compose",), drop_paths=("usr/bin/docker-compose",)),
)

DEBIAN_TO_DOCKER = {src: rule.name for rule in RULES for src in rule.sources}
# Names Debian uses in Conflicts/Breaks to keep away from Docker's packages; they
# would point at our own packages (or ones we don't build), so they are dropped.
DOCKER_NAMES = {rule.name for rule in RULES} | {"docker-ce-rootless-extras"}

POSITIVE_FIELDS = ("Pre-Depends", "Depends", "Recommends", "Suggests", "Enhances")
NEGATIVE_FIELDS = ("Conflicts", "Breaks", "Replaces")
LEADING_FIELDS = ("Package", "Source", "Version", "Architecture", "Maintainer", "Installed-Size")


class MirrorError(RuntimeError):
    pass


# ---------------------------------------------------------------- timing / exec


@contextlib.contextmanager
def phase(name: str):
    start = time.monotonic()
    yield
    print(f"[mirror] {name}: {time.monotonic() - start:.1f}s", flush=True)


def run(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    if proc.returncode != 0:
        detail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        raise MirrorError(f"{cmd[0]} failed ({proc.returncode}): {' | '.join(detail)}")
    return proc


# ------------------------------------------------------------ deb822 / relations


def parse_paragraphs(text: str) -> list[dict[str, str]]:
    """Parse deb822 text into ordered dicts; continuation lines are kept verbatim."""
    paragraphs, current, key = [], {}, None
    for line in text.splitlines():
        if not line.strip():
            if current:
                paragraphs.append(current)
            current, key = {}, None
        elif line[0] in " \t":
            if key is None:
                raise ValueError(f"continuation line without a field: {line!r}")
            current[key] += "\n" + line
        else:
            key, _, value = line.partition(":")
            current[key] = value.strip()
    if current:
        paragraphs.append(current)
    return paragraphs


def format_paragraph(fields: dict[str, str]) -> str:
    return "".join(f"{k}: {v}\n" for k, v in fields.items())


_ALT_RE = re.compile(r"^([a-z0-9][a-z0-9+.-]*)(:[a-z0-9-]+)?\s*(?:\(\s*([<>=]+)\s*([^)\s]+)\s*\))?$")


@dataclasses.dataclass(frozen=True)
class Alt:
    name: str
    op: str | None = None
    version: str | None = None
    arch: str = ""

    def __str__(self) -> str:
        rel = f" ({self.op} {self.version})" if self.op else ""
        return f"{self.name}{self.arch}{rel}"


def parse_relations(value: str) -> list[list[Alt]]:
    """'a (>= 1), b | c' -> [[Alt(a, >=, 1)], [Alt(b), Alt(c)]]"""
    groups = []
    for group in " ".join(value.split()).split(","):
        if not group.strip():
            continue
        alts = []
        for alt in group.split("|"):
            m = _ALT_RE.match(alt.strip())
            if not m:
                raise ValueError(f"cannot parse relation {alt.strip()!r}")
            alts.append(Alt(m[1], m[3], m[4], m[2] or ""))
        groups.append(alts)
    return groups


def format_relations(groups: list[list[Alt]]) -> str:
    return ", ".join(" | ".join(str(a) for a in g) for g in groups)


def _dedupe(groups: list[list[Alt]]) -> list[list[Alt]]:
    seen, out = set(), []
    for g in groups:
        key = tuple(g)
        if key not in seen:
            seen.add(key)
            out.append(g)
    return out


def _merge_lower_bounds(groups: list[list[Alt]]) -> list[list[Alt]]:
    """Merging packages gives 'libc6 (>= 2.34), libc6 (>= 2.38)': keep the stronger."""

    def lower_bound(g):
        return g[0] if len(g) == 1 and g[0].op == ">=" else None

    best: dict[str, Alt] = {}
    for g in groups:
        a = lower_bound(g)
        if a and (a.name not in best or compare_versions(a.version, best[a.name].version) > 0):
            best[a.name] = a
    out, emitted = [], set()
    for g in groups:
        a = lower_bound(g)
        if a:
            if a.name in emitted:
                continue
            emitted.add(a.name)
            g = [best[a.name]]
        out.append(g)
    return out


# ---------------------------------------------------------------- versions


def _order(c: str) -> int:
    if c == "~":
        return -1
    if c.isalpha():
        return ord(c)
    return ord(c) + 256


def _compare_part(a: str, b: str) -> int:
    """dpkg's comparison of an upstream version or revision string."""
    while a or b:
        na = re.match(r"^[^0-9]*", a)[0]
        nb = re.match(r"^[^0-9]*", b)[0]
        for i in range(max(len(na), len(nb))):
            ca = _order(na[i]) if i < len(na) else 0
            cb = _order(nb[i]) if i < len(nb) else 0
            if ca != cb:
                return -1 if ca < cb else 1
        a, b = a[len(na) :], b[len(nb) :]
        da = re.match(r"^[0-9]*", a)[0]
        db = re.match(r"^[0-9]*", b)[0]
        if int(da or 0) != int(db or 0):
            return -1 if int(da or 0) < int(db or 0) else 1
        a, b = a[len(da) :], b[len(db) :]
    return 0


def compare_versions(a: str, b: str) -> int:
    """-1, 0, 1 like `dpkg --compare-versions`."""

    def split(v):
        epoch, _, rest = v.partition(":") if ":" in v else ("0", "", v)
        upstream, _, revision = rest.rpartition("-") if "-" in rest else (rest, "", "")
        return int(epoch or 0), upstream, revision

    ea, ua, ra = split(a)
    eb, ub, rb = split(b)
    if ea != eb:
        return -1 if ea < eb else 1
    return _compare_part(ua, ub) or _compare_part(ra, rb)


def upstream_version(debian_version: str) -> str:
    """'1:26.1.5+dfsg1-9+deb13u1' -> '26.1.5' (epoch, revision, repack suffix gone)."""
    v = debian_version.split(":", 1)[-1]
    if "-" in v:
        v = v.rsplit("-", 1)[0]
    return re.sub(r"[+~](dfsg|ds)\d*.*$", "", v)


def docker_version(rule: Rule, debian_version: str) -> str:
    """Docker's scheme: '5:26.1.5-1~debian.13~trixie', containerd.io: '1.7.24-1'."""
    v = f"{upstream_version(debian_version)}-1"
    if rule.distro_suffix:
        v += f"~debian.{DEBIAN_RELEASE}~{SUITE}"
    return f"{rule.epoch}:{v}" if rule.epoch else v


# ---------------------------------------------------------- control rewriting


def rewrite_control(rule: Rule, controls: list[dict[str, str]], version: str) -> dict[str, str]:
    """Build the control paragraph of ``rule.name`` from its Debian sources' ones."""
    primary = controls[0]
    out = dict(primary)

    for field in POSITIVE_FIELDS:
        groups = []
        for ctl in controls:
            groups += parse_relations(ctl.get(field, ""))
        renamed = []
        for g in groups:
            # A renamed alternative loses its version: Debian's numbers mean nothing
            # against ours (and it is one of our own packages anyway).
            g = [Alt(DEBIAN_TO_DOCKER[a.name]) if a.name in DEBIAN_TO_DOCKER else a for a in g]
            if any(a.name == rule.name for a in g):
                continue  # satisfied by the package itself (merged containerd+runc)
            g = [a for a in g if a.name not in rule.drop_relations]
            if g:
                renamed.append(g)
        renamed += [[Alt(n)] for n in {"Depends": rule.add_depends, "Recommends": rule.add_recommends}.get(field, ())]
        if renamed:
            out[field] = format_relations(_merge_lower_bounds(_dedupe(renamed)))
        else:
            out.pop(field, None)

    depends = {tuple(g) for g in parse_relations(out.get("Depends", ""))}
    for weaker in ("Recommends", "Suggests"):
        if weaker in out:
            kept = [g for g in parse_relations(out[weaker]) if tuple(g) not in depends]
            out[weaker] = format_relations(kept)
            if not kept:
                del out[weaker]

    own_debian_names = [[Alt(s)] for s in rule.sources]
    for field in NEGATIVE_FIELDS + ("Provides",):
        groups = []
        for ctl in controls:
            groups += [g for g in parse_relations(ctl.get(field, "")) if not any(a.name in DOCKER_NAMES for a in g)]
        if field != "Breaks":
            groups += own_debian_names
        if groups:
            out[field] = format_relations(_dedupe(groups))
        else:
            out.pop(field, None)

    built_using = []
    for ctl in controls:
        built_using += parse_relations(ctl.get("Built-Using", ""))
    if built_using:
        out["Built-Using"] = format_relations(_dedupe(built_using))

    # "Source: runc (1.1.15+ds1-2)" names the source version of a binNMU'd package.
    src_field = primary.get("Source", primary["Package"])
    src = src_field.split()[0]
    src_version = src_field.split("(", 1)[1].rstrip(") ") if "(" in src_field else primary["Version"]
    repacked = ", ".join(f"{c['Package']} {c['Version']}" for c in controls)
    description = primary["Description"] + (
        f"\n .\n Lab repackaging of Debian {SUITE} {repacked} under Docker's package name."
    )

    out.update(
        {
            "Package": rule.name,
            "Source": f"{src} ({src_version})",
            "Version": version,
            "Maintainer": LAB_MAINTAINER,
            "Installed-Size": str(sum(int(c.get("Installed-Size", 0)) for c in controls)),
        }
    )
    out.pop("Description")
    ordered = {k: out[k] for k in LEADING_FIELDS if k in out}
    ordered.update({k: v for k, v in out.items() if k not in ordered})
    ordered["Description"] = description
    return ordered


# ------------------------------------------------------------ index / Release

HASHES = (("MD5Sum", "md5"), ("SHA1", "sha1"), ("SHA256", "sha256"), ("SHA512", "sha512"))


def file_hashes(data: bytes) -> dict[str, str]:
    return {algo: hashlib.new(algo, data).hexdigest() for _, algo in HASHES}


def packages_entry(control: dict[str, str], filename: str, data: bytes) -> str:
    h = file_hashes(data)
    fields = dict(control)
    fields.update(
        {"Filename": filename, "Size": str(len(data)), "MD5sum": h["md5"], "SHA1": h["sha1"], "SHA256": h["sha256"]}
    )
    return format_paragraph(fields)


def release_date(t: float) -> str:
    # Locale-independent RFC 2822 date, as apt expects.
    days = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")
    months = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")
    tm = time.gmtime(t)
    return (
        f"{days[tm.tm_wday]}, {tm.tm_mday:02d} {months[tm.tm_mon - 1]} {tm.tm_year} "
        f"{tm.tm_hour:02d}:{tm.tm_min:02d}:{tm.tm_sec:02d} UTC"
    )


def release_text(index_files: dict[str, bytes], date: str, arches: tuple[str, ...] = ARCHES) -> str:
    """Release for dists/<suite>; index_files maps paths relative to it to content."""
    lines = [
        "Origin: Docker",
        "Label: Docker",
        f"Suite: {SUITE}",
        f"Codename: {SUITE}",
        f"Architectures: {' '.join(arches)}",
        f"Components: {COMPONENT}",
        f"Description: Robot lab stand-in for Docker CE packages for Debian {SUITE}",
        f"Date: {date}",
    ]
    hashed = {path: file_hashes(data) for path, data in sorted(index_files.items())}
    for field, algo in HASHES:
        lines.append(f"{field}:")
        for path, h in hashed.items():
            lines.append(f" {h[algo]} {len(index_files[path]):>16} {path}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- apt (trixie)


def debian_url() -> str:
    """This machine's Debian archive (its apt sources; ROBOT_LAB_DEBIAN_URL overrides)."""
    try:
        return debian_archive_url()
    except ArchiveError as error:
        raise MirrorError(str(error)) from None


class TrixieApt:
    """apt-get/apt-cache against trixie main as a system of one architecture
    sees it, with private state: the machine's own apt configuration and
    package lists are left alone."""

    def __init__(self, work: Path, arch: str = "amd64"):
        self.work = work
        self.arch = arch
        (work / "lists" / "partial").mkdir(parents=True, exist_ok=True)
        (work / "archives" / "partial").mkdir(parents=True, exist_ok=True)
        self.sources = work / "sources.list"
        self.sources.write_text(f"deb [signed-by={DEBIAN_KEYRING}] {debian_url()} {SUITE} main\n")
        self.status = work / "status"
        self.status.touch()

    def options(self) -> list[str]:
        opts = {
            "Dir::Etc::SourceList": self.sources,
            "Dir::Etc::SourceParts": "/dev/null",
            "Dir::Etc::Preferences": "/dev/null",
            "Dir::Etc::PreferencesParts": "/dev/null",
            "Dir::State": self.work,
            "Dir::State::Lists": self.work / "lists",
            "Dir::State::status": self.status,
            "Dir::Cache": self.work,
            "Dir::Cache::Archives": self.work / "archives",
            "APT::Architecture": self.arch,
            "APT::Architectures": self.arch,
            "APT::Sandbox::User": "root",  # _apt cannot write into the cache dir
            "Acquire::Languages": "none",
        }
        return [a for k, v in opts.items() for a in ("-o", f"{k}={v}")]

    def apt_get(self, *args: str, cwd: Path | None = None) -> str:
        return run(["apt-get", "-q", *self.options(), *args], cwd=cwd).stdout

    def show(self, names: list[str]) -> dict[str, dict[str, str]]:
        out = run(["apt-cache", *self.options(), "show", "--no-all-versions", *names]).stdout
        return {p["Package"]: p for p in parse_paragraphs(out)}


def resolve_sources(apt: TrixieApt) -> dict[str, str]:
    """name -> version of every source package, for ``apt``'s architecture."""
    apt.apt_get("update")
    names = [s for rule in RULES for s in rule.sources]
    found = apt.show(names)
    missing = [n for n in names if n not in found]
    if missing:
        raise MirrorError(f"not in Debian {SUITE} main for {apt.arch}: {', '.join(missing)}")
    return {n: found[n]["Version"] for n in names}


def deb_filename(name: str, version: str, arch: str) -> str:
    return f"{name}_{version.split(':', 1)[-1]}_{arch}.deb"


def fetch_sources(apt: TrixieApt, versions: dict[str, str], dest: Path) -> None:
    """The debs of ``versions`` for ``apt``'s architecture into ``dest``
    (shared by every architecture: the file names say which)."""
    dest.mkdir(parents=True, exist_ok=True)
    wanted = {deb_filename(n, v, apt.arch): (n, v) for n, v in versions.items()}
    todo = [f"{n}={v}" for fn, (n, v) in wanted.items() if not (dest / fn).exists()]
    if todo:
        with tempfile.TemporaryDirectory(dir=dest) as tmp:
            apt.apt_get("download", *todo, cwd=Path(tmp))
            for f in Path(tmp).glob("*.deb"):
                name, ver = f.name.split("_")[:2]
                f.rename(dest / deb_filename(name, ver.replace("%3a", ":"), apt.arch))


def prune_sources(dest: Path, wanted: set[str]) -> None:
    for f in dest.glob("*.deb"):
        if f.name not in wanted:
            f.unlink()


# ---------------------------------------------------------------- repackaging


def repack(
    rule: Rule, debs: list[Path], versions: dict[str, str], out_dir: Path, work: Path, arch: str
) -> tuple[Path, dict[str, str]]:
    tree = work / rule.name
    shutil.rmtree(tree, ignore_errors=True)
    work.mkdir(parents=True, exist_ok=True)
    run(["dpkg-deb", "-R", str(debs[0]), str(tree)])
    meta = tree / "DEBIAN"
    controls = [parse_paragraphs((meta / "control").read_text())[0]]

    for extra in debs[1:]:
        ctl_dir = work / f"{rule.name}.{extra.name}.control"
        shutil.rmtree(ctl_dir, ignore_errors=True)
        run(["dpkg-deb", "-e", str(extra), str(ctl_dir)])
        scripts = [
            p.name for p in ctl_dir.iterdir() if p.name in ("preinst", "postinst", "prerm", "postrm", "triggers")
        ]
        if scripts:
            raise MirrorError(f"{extra.name}: cannot merge maintainer scripts {scripts}")
        controls.append(parse_paragraphs((ctl_dir / "control").read_text())[0])
        run(["dpkg-deb", "-x", str(extra), str(tree)])
        for listing in ("md5sums", "conffiles"):
            if (ctl_dir / listing).exists():
                with open(meta / listing, "a") as f:
                    f.write((ctl_dir / listing).read_text())
        shutil.rmtree(ctl_dir)

    for rel in rule.drop_paths:
        target = tree / rel
        if not target.is_symlink() and not target.exists():
            raise MirrorError(f"{rule.name}: drop path {rel} not in {debs[0].name}")
        target.unlink()
        md5 = meta / "md5sums"
        if md5.exists():
            md5.write_text(
                "".join(line for line in md5.read_text().splitlines(True) if line.split(None, 1)[1].strip() != rel)
            )

    for rel, target in rule.add_symlinks:
        link = tree / rel
        if link.exists() or link.is_symlink():
            raise MirrorError(f"{rule.name}: {rel} already exists in {debs[0].name}")
        link.symlink_to(target)
        if not link.exists():
            raise MirrorError(f"{rule.name}: symlink {rel} -> {target} dangles")

    version = docker_version(rule, versions[rule.sources[0]])
    control = rewrite_control(rule, controls, version)
    (meta / "control").write_text(format_paragraph(control))

    deb = out_dir / deb_filename(rule.name, version, arch)
    # zstd: xz recompression of these ~100 MB Go binaries takes minutes on 2 cores.
    run(["dpkg-deb", "--root-owner-group", "-Zzstd", "-b", str(tree), str(deb)])
    shutil.rmtree(tree)
    return deb, control


def pool_rel(arch: str) -> str:
    return f"pool/{COMPONENT}/{arch}"


def check_installable(apt: TrixieApt, debs: list[Path]) -> None:
    """Simulate installing the set on an empty trixie system: every dependency
    must resolve from trixie main or from the set itself."""
    apt.apt_get("install", "-s", "--no-install-recommends", *[str(d) for d in debs])


# ---------------------------------------------------------------- signing


class LabKey:
    def __init__(self, home: Path):
        self.home = home
        home.mkdir(parents=True, exist_ok=True)
        home.chmod(0o700)

    def gpg(self, *args: str) -> str:
        return run(["gpg", "--batch", "--yes", "--homedir", str(self.home), *args]).stdout

    def fingerprint(self) -> str | None:
        out = self.gpg("--with-colons", "--list-secret-keys")
        fprs = [line.split(":")[9] for line in out.splitlines() if line.startswith("fpr:")]
        return fprs[0].upper() if fprs else None

    def ensure(self) -> str:
        if not self.fingerprint():
            self.gpg(
                "--passphrase",
                "",
                "--pinentry-mode",
                "loopback",
                "--quick-gen-key",
                KEY_UID,
                "ed25519",
                "sign",
                "never",
            )
        return self.fingerprint()

    def export_armored(self) -> bytes:
        return self.gpg("--armor", "--export", self.fingerprint()).encode()

    def sign(self, release: Path) -> None:
        common = ("--local-user", self.fingerprint(), "--digest-algo", "SHA512")
        self.gpg(*common, "--clearsign", "-o", str(release.with_name("InRelease")), str(release))
        self.gpg(*common, "--armor", "--detach-sign", "-o", str(release.with_name("Release.gpg")), str(release))

    def stop_agent(self) -> None:
        subprocess.run(["gpgconf", "--homedir", str(self.home), "--kill", "gpg-agent"], capture_output=True)


# ---------------------------------------------------------------- build


def rules_digest() -> str:
    """The repack rules and the code applying them: any edit here rebuilds."""
    h = hashlib.sha256(json.dumps([SUITE, [dataclasses.asdict(r) for r in RULES]], sort_keys=True).encode())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()


def recipe_digest(sources: dict[str, dict[str, str]]) -> str:
    """``sources``: arch -> name -> version."""
    payload = json.dumps([rules_digest(), {arch: sorted(v.items()) for arch, v in sorted(sources.items())}])
    return hashlib.sha256(payload.encode()).hexdigest()


def _complete(out_dir: Path, manifest: dict) -> bool:
    root = out_dir / "repo"
    return all(
        (root / rel).is_file() and (root / rel).stat().st_size == size
        for rel, size in manifest.get("files", {}).items()
    ) and bool(manifest.get("files"))


def _result(out_dir: Path, manifest: dict) -> dict:
    return {
        "root": str(out_dir / "repo"),
        **{k: manifest[k] for k in ("fingerprint", "key_sha256", "packages", "sources")},
    }


def build_mirror(out_dir: Path = DEFAULT_OUT_DIR, refresh: bool = False) -> dict:
    """Build (or reuse) the mirror; returns root, fingerprint, key_sha256, packages."""
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = out_dir / "manifest.json"
    with open(out_dir / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
        fresh = manifest.get("rules") == rules_digest() and _complete(out_dir, manifest)
        if fresh and not refresh:
            print(f"[mirror] cached: {out_dir}", flush=True)
            return _result(out_dir, manifest)

        start = time.monotonic()
        apts = {arch: TrixieApt(out_dir / ("apt" if arch == "amd64" else f"apt-{arch}"), arch) for arch in ARCHES}
        with phase("resolve trixie sources"):
            sources = {arch: resolve_sources(apt) for arch, apt in apts.items()}
        if fresh and manifest.get("recipe") == recipe_digest(sources):
            print(f"[mirror] up to date: {out_dir}", flush=True)
            return _result(out_dir, manifest)

        src_dir = out_dir / "debian-src"
        with phase("download"):
            for arch, apt in apts.items():
                fetch_sources(apt, sources[arch], src_dir)
            prune_sources(
                src_dir, {deb_filename(n, v, arch) for arch, versions in sources.items() for n, v in versions.items()}
            )

        staging = out_dir / "staging"
        shutil.rmtree(staging, ignore_errors=True)
        dist = staging / "repo" / "linux" / "debian"
        built: dict[str, list[tuple[Path, dict[str, str]]]] = {}
        with phase("repack"):
            for arch in ARCHES:
                (dist / pool_rel(arch)).mkdir(parents=True)
                built[arch] = [
                    repack(
                        rule,
                        [src_dir / deb_filename(s, sources[arch][s], arch) for s in rule.sources],
                        sources[arch],
                        dist / pool_rel(arch),
                        staging / "work",
                        arch,
                    )
                    for rule in RULES
                ]
            shutil.rmtree(staging / "work")
        with phase("check installable"):
            for arch, apt in apts.items():
                check_installable(apt, [deb for deb, _ in built[arch]])

        key = LabKey(out_dir / "gnupg")
        try:
            with phase("index + sign"):
                fingerprint = key.ensure()
                public_key = key.export_armored()
                (dist / "gpg").write_bytes(public_key)
                indexes = {}
                for arch in ARCHES:
                    packages = "\n".join(
                        packages_entry(ctl, f"{pool_rel(arch)}/{deb.name}", deb.read_bytes())
                        for deb, ctl in built[arch]
                    ).encode()
                    index_rel = f"{COMPONENT}/binary-{arch}/Packages"
                    indexes.update({index_rel: packages, index_rel + ".gz": gzip.compress(packages, mtime=0)})
                suite_dir = dist / "dists" / SUITE
                for rel, data in indexes.items():
                    (suite_dir / rel).parent.mkdir(parents=True, exist_ok=True)
                    (suite_dir / rel).write_bytes(data)
                (suite_dir / "Release").write_text(release_text(indexes, release_date(time.time())))
                key.sign(suite_dir / "Release")
        finally:
            key.stop_agent()

        root = staging / "repo"
        manifest = {
            "recipe": recipe_digest(sources),
            "rules": rules_digest(),
            "fingerprint": fingerprint,
            "key_sha256": hashlib.sha256(public_key).hexdigest(),
            "packages": {ctl["Package"]: ctl["Version"] for _, ctl in built["amd64"]},
            "architectures": {arch: {ctl["Package"]: ctl["Version"] for _, ctl in built[arch]} for arch in ARCHES},
            "sources": sources,
            "files": {str(p.relative_to(root)): p.stat().st_size for p in sorted(root.rglob("*")) if p.is_file()},
        }
        shutil.rmtree(out_dir / "repo", ignore_errors=True)
        root.rename(out_dir / "repo")
        shutil.rmtree(staging)
        manifest_path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
        print(f"[mirror] built in {time.monotonic() - start:.1f}s: {out_dir}", flush=True)
        return _result(out_dir, manifest)


def main(argv: list[str]) -> int:
    refresh = "--refresh" in argv
    args = [a for a in argv if a != "--refresh"]
    out_dir = Path(args[0]) if args else DEFAULT_OUT_DIR
    try:
        result = build_mirror(out_dir, refresh=refresh)
    except (MirrorError, OSError) as e:
        print(f"[mirror] error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
