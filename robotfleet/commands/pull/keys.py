"""Make, show and rotate the keys that sign pull releases; keep the root key offline.

    robotfleet keys init                          the root key and the online key, in the key directory
    robotfleet keys show                          the repository's root: version, expiry, key ids
    robotfleet keys rotate online|root            a new key, its root change signed here (root key at hand)
  with the root key offline (three steps, the middle one on the offline machine):
    robotfleet keys prepare online|root|renew --out next-root.json [--root-public NEW.pub]
    robotfleet keys sign next-root.json --key /media/offline/root.key [--key NEW.key]
    robotfleet keys install next-root.json
    robotfleet keys generate FILE.key             a new key anywhere (a new root key, offline)

The key directory: --keys DIR, else $ROBOTFLEET_KEYS, else
~/.config/robotfleet/keys; private keys are 0600 files there and are never
printed.  The root key signs only a new root (the first publish, a key
change, a renewal of the root's year); the online key signs every publish.
A new root is signed by the old root key and, for a root key change, by the
new one too; robots that trust the old root follow the chain.  Where each
option goes: --remote/--to-dir as for publish.  See docs/guides/pull.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from robotfleet import commands, selection
from robotfleet.pull.operator import commandline
from robotfleet.pull.operator import keys as keyfiles
from robotfleet.pull.operator.keys import ONLINE, ROOT
from robotfleet.pull.operator.root_ceremony import install_root, prepare_root, sign_root

NEXT_ONLINE, NEXT_ROOT = "online.next", "root.next"


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet keys``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("keys", __doc__)
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    init = sub.add_parser("init", help="make the root key and the online key")
    init.add_argument("--keys", type=Path, metavar="DIR", help="the key directory")
    show = sub.add_parser("show", help="the repository's root and which keys are here")
    rotate = sub.add_parser("rotate", help="replace a key now (the root key must be at hand)")
    rotate.add_argument("which", choices=("online", "root"))
    rotate.add_argument(
        "--root-key", type=Path, metavar="FILE", help="the current root key (default: the key directory's)"
    )
    prepare = sub.add_parser("prepare", help="write the next root, unsigned, for the offline root key to sign")
    prepare.add_argument("which", choices=("online", "root", "renew"))
    prepare.add_argument("--out", type=Path, required=True, metavar="FILE")
    prepare.add_argument("--root-public", type=Path, metavar="FILE.pub", help="the new root key's public file (root)")
    sign = sub.add_parser("sign", help="sign a prepared root with private key files (offline)")
    sign.add_argument("file", type=Path)
    sign.add_argument("--key", type=Path, action="append", required=True, metavar="FILE.key")
    install = sub.add_parser("install", help="publish a signed root and re-sign the rest with the online key")
    install.add_argument("file", type=Path)
    generate = sub.add_parser("generate", help="a new key pair at FILE.key and FILE.pub")
    generate.add_argument("file", type=Path)
    for each in (show, rotate, prepare, install):
        commandline.add_channel(each)
        commandline.add_expiry(each)
    return parser


def _says(public) -> str:
    return f"{public.keytype} {public.keyid[:16]}"


def init(args) -> int:
    keys = commandline.keys_of(args)
    made = [(name, keys.generate(name)) for name in (ROOT, ONLINE)]
    for name, public in made:
        print(f"keys: {keys.file(name)} ({_says(public)})")
    print(
        "keys: the first publish signs the repository's root with the root key; then move "
        f"{keys.file(ROOT)} to offline storage (docs/guides/pull.md)"
    )
    return selection.OK


def show(args) -> int:
    keys = commandline.keys_of(args)
    chosen, repository = commandline.opened(args, writes=False)
    if not repository.exists():
        raise commandline.Failed(f"{chosen.url}: no release repository yet; the first robotfleet publish makes it")
    root = repository.root().signed
    print(f"root version {root.version}, expires {root.expires:%Y-%m-%dT%H:%M:%SZ}")
    for role, info in sorted(root.roles.items()):
        print(f"  {role:9} threshold {info.threshold}: {', '.join(k[:16] for k in info.keyids)}")
    for name in (ROOT, ONLINE, NEXT_ONLINE, NEXT_ROOT):
        if keys.has(name):
            print(f"  here: {keys.file(name)} ({_says(keys.public(name))})")
    record = repository.record()
    if record:
        print(
            f"release {record.version} ({record.release}){' HALTED' if record.halt else ''}, "
            f"timestamp expires {repository.timestamp().signed.expires:%Y-%m-%dT%H:%M:%SZ}"
        )
    return selection.OK


def _next_key(keys, name: str):
    return keys.public(name) if keys.has(name) else keys.generate(name)


def prepare(args) -> int:
    keys, expiry = commandline.keys_of(args), commandline.expiry_of(args)
    chosen, repository = commandline.opened(args, writes=False)
    if not repository.exists():
        raise commandline.Failed(f"{chosen.url}: no release repository yet; the first robotfleet publish makes it")
    online = root_key = None
    if args.which == "online":
        online = _next_key(keys, NEXT_ONLINE)
    elif args.which == "root":
        if not args.root_public:
            raise commandline.Failed(
                "prepare root needs --root-public NEW.pub: make the new root key offline first "
                "(robotfleet keys generate NEW.key) and give its .pub file"
            )
        root_key = keyfiles.public_of(args.root_public)
    data = prepare_root(repository, expiry, commandline.now(), online_key=online, root_key=root_key)
    args.out.write_bytes(data)
    version = repository.root().signed.version + 1
    signers = "the current root key" + (" and the new root key" if root_key else "")
    print(
        f"keys: root version {version} written to {args.out}, unsigned; sign it with {signers} "
        f"(robotfleet keys sign {args.out} --key ...), then robotfleet keys install {args.out}"
    )
    return selection.OK


def sign(args) -> int:
    signers = [keyfiles.signer_of(path) for path in args.key]
    try:
        data = sign_root(args.file.read_bytes(), signers)
    except OSError as error:
        raise commandline.Failed(f"{args.file}: {error.strerror}") from None
    temp = args.file.with_name(f".{args.file.name}.tmp")
    temp.write_bytes(data)
    temp.replace(args.file)
    print(f"keys: {args.file} signed by {', '.join(_says(s.public_key) for s in signers)}")
    return selection.OK


def _install(args, data: bytes, keys, promote: list[tuple[str, str]]) -> int:
    expiry = commandline.expiry_of(args)
    chosen, repository = commandline.opened(args)
    online_name = NEXT_ONLINE if (NEXT_ONLINE, ONLINE) in promote else ONLINE
    version = install_root(repository, data, keys.signer(online_name), expiry, commandline.now())
    where = commandline.pushed(chosen, f"root version {version}")
    for name, replaced in promote:
        keys.promote(name, replaced)
    print(f"keys: root version {version} installed; targets, snapshot and timestamp re-signed; {where}")
    return selection.OK


def install(args) -> int:
    keys = commandline.keys_of(args)
    try:
        data = args.file.read_bytes()
    except OSError as error:
        raise commandline.Failed(f"{args.file}: {error.strerror}") from None
    from tuf.api.metadata import Metadata

    names = set(Metadata.from_bytes(data).signed.roles["timestamp"].keyids)
    promote = [(NEXT_ONLINE, ONLINE)] if keys.has(NEXT_ONLINE) and keys.public(NEXT_ONLINE).keyid in names else []
    return _install(args, data, keys, promote)


def rotate(args) -> int:
    keys, expiry = commandline.keys_of(args), commandline.expiry_of(args)
    root_signer = keyfiles.signer_of(args.root_key) if args.root_key else keys.signer(ROOT)
    chosen, repository = commandline.opened(args)
    if not repository.exists():
        raise commandline.Failed(f"{chosen.url}: no release repository yet; the first robotfleet publish makes it")
    if args.which == "online":
        new = _next_key(keys, NEXT_ONLINE)
        data = sign_root(prepare_root(repository, expiry, commandline.now(), online_key=new), [root_signer])
        return _install(args, data, keys, [(NEXT_ONLINE, ONLINE)])
    new = _next_key(keys, NEXT_ROOT)
    unsigned = prepare_root(repository, expiry, commandline.now(), root_key=new)
    data = sign_root(unsigned, [root_signer, keys.signer(NEXT_ROOT)])
    return _install(args, data, keys, [(NEXT_ROOT, ROOT)])


def generate(args) -> int:
    public = keyfiles.generate(args.file)
    print(f"keys: {args.file} ({_says(public)}); its public file {args.file.with_suffix('.pub')}")
    return selection.OK


ACTIONS = {
    "init": init,
    "show": show,
    "rotate": rotate,
    "prepare": prepare,
    "sign": sign,
    "install": install,
    "generate": generate,
}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return commandline.run("keys", lambda: ACTIONS[args.action](args))
