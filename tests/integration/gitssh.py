"""A git server over SSH on 127.0.0.1 for tests: paramiko's server side
(tests/integration/sshserver.py) running git's own ``git-upload-pack`` and
``git-receive-pack`` on the repositories under one directory, as gitolite
does (``git-upload-pack 'fleet'``), with the GIT_PROTOCOL the client sends.
Counts its sessions and the protocol-v2 commands each asked for."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import threading
from pathlib import Path

import paramiko

from tests.integration import sshserver

_COMMAND = re.compile(rb"command=([a-z-]+)")


class _GitServer(sshserver._Server):
    def __init__(self, owner: "GitSSHServer"):
        super().__init__(owner.client_key)
        self.owner, self.env = owner, {}

    def check_channel_env_request(self, channel, name, value):
        if name == b"GIT_PROTOCOL" or name == "GIT_PROTOCOL":
            self.env["GIT_PROTOCOL"] = value.decode() if isinstance(value, bytes) else value
            return True
        return False

    def check_channel_exec_request(self, channel, command):
        words = shlex.split(command.decode(errors="replace"))
        if len(words) != 2 or words[0] not in ("git-upload-pack", "git-receive-pack"):
            return False
        path = (self.owner.root / words[1].strip("/")).resolve()
        if self.owner.root.resolve() not in path.parents:
            return False
        self.owner.sessions.append(words[0])
        threading.Thread(target=self._run, args=(channel, words[0], path), daemon=True).start()
        return True

    def _run(self, channel, program: str, path: Path) -> None:
        env = {"PATH": os.environ["PATH"], "HOME": str(self.owner.root), **self.env}
        process = subprocess.Popen(
            ["git", program.removeprefix("git-"), str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
        )

        def feed():
            while data := channel.recv(65536):
                self.owner.commands.extend(m.decode() for m in _COMMAND.findall(data))
                try:
                    process.stdin.write(data)
                    process.stdin.flush()
                except OSError:
                    break
            try:
                process.stdin.close()
            except OSError:
                pass

        threading.Thread(target=feed, daemon=True).start()
        while data := process.stdout.read1(65536):
            channel.sendall(data)
        channel.send_exit_status(process.wait())
        channel.close()


class GitSSHServer(sshserver.Listener):
    """The bare repositories under ``root`` over SSH, for ``client_key``."""

    def __init__(self, root: Path, client_key: paramiko.PKey):
        self.root, self.sessions, self.commands = Path(root), [], []
        super().__init__(
            host_key=paramiko.Ed25519Key.from_private_key_file(_host_key(self.root)), client_key=client_key
        )

    def _ssh(self, conn):
        transport = paramiko.Transport(conn)
        self.open.append(transport)
        transport.add_server_key(self.host_key)
        try:
            transport.start_server(server=_GitServer(self))
        except (paramiko.SSHException, EOFError, OSError):
            return

    def url(self, name: str) -> str:
        return f"ssh://git@127.0.0.1:{self.port}/{name}"

    def known_hosts(self, alias: str) -> str:
        return f"{alias} {self.host_key.get_name()} {self.host_key.get_base64()}\n"


def _host_key(root: Path) -> str:
    path = root / "ssh_host_ed25519_key"
    if not path.exists():
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(path)], check=True)
    return str(path)


def client_key(etc: Path) -> paramiko.PKey:
    """A new robot key at ``etc``/id_ed25519 (as the agent finds its own), as paramiko reads it."""
    key = etc / "id_ed25519"
    key.unlink(missing_ok=True)
    Path(f"{key}.pub").unlink(missing_ok=True)
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(key)], check=True)
    return paramiko.Ed25519Key.from_private_key_file(str(key))
