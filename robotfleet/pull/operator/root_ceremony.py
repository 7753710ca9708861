"""The root ceremony: the fleet's TUF root changed by hand (robotfleet keys
prepare, sign, install, rotate).  The next root is prepared unsigned (a new
online key, a new root key, a new expiry), signed where the root keys are
(offline), and installed only as the next version signed by the current
root's key and by its own; the online roles are then re-signed under it.
Publishing releases under the root is robotfleet/pull/operator/repository.py's."""

from __future__ import annotations

import datetime

from tuf.api.metadata import Metadata, Root

from robotfleet.pull.operator.repository import ONLINE_ROLES, SERIALIZER, Expiry, Repository, RepositoryError, expires


def prepare_root(
    repository: Repository, expiry: Expiry, now: datetime.datetime, online_key=None, root_key=None
) -> bytes:
    """The next root, unsigned: the same keys but ``online_key`` (a new
    online key for targets, snapshot, timestamp) and ``root_key`` (a new
    root key) where given, a new expiry.  It must be signed by the
    current root key (and by ``root_key`` if given) before install_root."""
    root = repository.root()
    root.signatures.clear()
    root.signed.version += 1
    root.signed.expires = expires(now, expiry.root)
    changes = [(role, online_key) for role in ONLINE_ROLES if online_key is not None]
    if root_key is not None:
        changes.append((Root.type, root_key))
    for role, key in changes:
        for keyid in list(root.signed.roles[role].keyids):
            root.signed.revoke_key(keyid, role)
        root.signed.add_key(key, role)
    return root.to_bytes(SERIALIZER)


def install_root(repository: Repository, data: bytes, online_signer, expiry: Expiry, now: datetime.datetime) -> int:
    """Make the signed root ``data`` current: it must be the next version,
    signed by the current root's threshold and by its own; then targets,
    snapshot and timestamp are re-signed with ``online_signer`` (the key
    the new root names).  Its version."""
    current = repository.root()
    try:
        new = Metadata[Root].from_bytes(data)
    except Exception as error:
        raise RepositoryError(f"not TUF root metadata ({str(error).splitlines()[0]})") from None
    if not isinstance(new.signed, Root):
        raise RepositoryError(f"{new.signed.type} metadata, not a root")
    if new.signed.version != current.signed.version + 1:
        raise RepositoryError(
            f"root version {new.signed.version}: the next root is version {current.signed.version + 1}"
        )
    for signer_root, who in ((current.signed, "the current root key"), (new.signed, "its own root key")):
        result = signer_root.get_verification_result(Root.type, new.signed_bytes, new.signatures)
        if not result.verified:
            raise RepositoryError(
                f"root version {new.signed.version} is not signed by {who} "
                f"({len(result.signed)} of {result.threshold} signatures); robotfleet keys sign"
            )
    for role in ONLINE_ROLES:
        if online_signer.public_key.keyid not in new.signed.roles[role].keyids:
            raise RepositoryError(
                f"root version {new.signed.version} does not name the online key "
                f"{online_signer.public_key.keyid[:16]} for {role}"
            )
    repository.write_root(data, new.signed.version)
    repository.resign(online_signer, expiry, now)
    return new.signed.version


def sign_root(data: bytes, signers) -> bytes:
    """A root's bytes with one more signature from each of ``signers`` (the
    offline step: robotfleet keys sign)."""
    md = Metadata[Root].from_bytes(data)
    if not isinstance(md.signed, Root):
        raise RepositoryError(f"not a root but {md.signed.type} metadata")
    for signer in signers:
        md.sign(signer, append=True)
    return md.to_bytes(SERIALIZER)
