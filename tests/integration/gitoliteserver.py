"""Debian's gitolite3 on 127.0.0.1 for tests: gitolite itself (its admin
repository, its compiled rules, its own ``~/.ssh/authorized_keys``) in a
directory that is its HOME, behind paramiko's SSH server
(tests/integration/sshserver.py) standing in for sshd: a client's key is
the user gitolite's authorized_keys names for it (``command="...
gitolite-shell USER"``, re-read at each login, as sshd reads it), and each
session runs that command with SSH_ORIGINAL_COMMAND, stderr included (where
gitolite says DENIED), as sshd would.  Set up as the lab's git server is
(tests/lab/gitserver.py): its rc lets the fleet's rules set
receive.maxInputSize, robotfleet's hooks (files/git-server/) are its common
hooks.  Needs the gitolite3 package (.ci/setup installs it)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import threading
from pathlib import Path

import paramiko

from tests.integration import sshserver
from tests.lab.gitserver import HOOK_FILES, RC_CONFIG_KEYS

_ENTRY = re.compile(r'command="(?P<shell>[^"]+) (?P<user>[^" ]+)",\S+ (?P<type>\S+) (?P<key>\S+)')
INSTALLED = shutil.which("gitolite") is not None


class _GitoliteSSH(sshserver._Server):
    def __init__(self, owner: GitoliteServer):
        super().__init__(None)
        self.owner, self.user, self.env = owner, None, {}

    def check_auth_publickey(self, username, key):
        found = self.owner.users().get(key.get_base64())
        if found is None:
            return paramiko.AUTH_FAILED
        self.user = found
        return paramiko.AUTH_SUCCESSFUL

    def check_channel_env_request(self, channel, name, value):
        if name in (b"GIT_PROTOCOL", "GIT_PROTOCOL"):
            self.env["GIT_PROTOCOL"] = value.decode() if isinstance(value, bytes) else value
            return True
        return False

    def check_channel_exec_request(self, channel, command):
        threading.Thread(target=self._run, args=(channel, command.decode(errors="replace")), daemon=True).start()
        return True

    def _run(self, channel, command: str) -> None:
        shell, user = self.user
        env = {
            "PATH": os.environ["PATH"],
            "HOME": str(self.owner.home),
            "SSH_ORIGINAL_COMMAND": command,
            "SSH_CONNECTION": f"127.0.0.1 1 127.0.0.1 {self.owner.port}",
            **self.env,
        }
        process = subprocess.Popen(
            [shell, user], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env
        )

        def feed():
            while data := channel.recv(65536):
                try:
                    process.stdin.write(data)
                    process.stdin.flush()
                except OSError:
                    break
            try:
                process.stdin.close()
            except OSError:
                pass

        def errors():
            while data := process.stderr.read1(65536):
                channel.sendall_stderr(data)

        threading.Thread(target=feed, daemon=True).start()
        said = threading.Thread(target=errors, daemon=True)
        said.start()
        while data := process.stdout.read1(65536):
            channel.sendall(data)
        said.join(30)
        channel.send_exit_status(process.wait())
        channel.close()


class GitoliteServer(sshserver.Listener):
    """gitolite3 with its HOME in ``base``/home, ``admin_key`` (a private
    key file, ``.pub`` beside it) its admin, user ``admin``."""

    def __init__(self, base: Path, admin_key: Path):
        self.base, self.home = Path(base), Path(base) / "home"
        self.home.mkdir(parents=True)
        admin_pub = self.base / "admin.pub"  # gitolite names the user by the file
        admin_pub.write_text(Path(f"{admin_key}.pub").read_text())
        self.gitolite("setup", "-pk", str(admin_pub))
        subprocess.run(["sh", "-c", RC_CONFIG_KEYS], env=dict(os.environ, HOME=str(self.home)), check=True)
        for hook, path in HOOK_FILES.items():
            shutil.copy(path, self.home / ".gitolite" / "hooks" / "common" / hook)
        self.gitolite("setup", "--hooks-only")
        host_key = self.base / "ssh_host_ed25519_key"
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(host_key)], check=True)
        super().__init__(host_key=paramiko.Ed25519Key.from_private_key_file(str(host_key)))

    def gitolite(self, *args: str) -> str:
        env = dict(os.environ, HOME=str(self.home))
        return subprocess.run(["gitolite", *args], env=env, check=True, capture_output=True, text=True).stdout

    def users(self) -> dict[str, tuple[str, str]]:
        """Key (base64) -> (gitolite-shell, user), as gitolite's authorized_keys has them now."""
        text = (self.home / ".ssh" / "authorized_keys").read_text()
        return {m["key"]: (m["shell"], m["user"]) for m in map(_ENTRY.match, text.splitlines()) if m}

    def _ssh(self, conn):
        transport = paramiko.Transport(conn)
        self.open.append(transport)
        transport.add_server_key(self.host_key)
        try:
            transport.start_server(server=_GitoliteSSH(self))
        except (paramiko.SSHException, EOFError, OSError):
            return

    @property
    def url(self) -> str:
        return f"ssh://gitolite3@127.0.0.1:{self.port}"

    def known_hosts(self, path: Path) -> str:
        path.write_text(f"[127.0.0.1]:{self.port} {self.host_key.get_name()} {self.host_key.get_base64()}\n")
        return str(path)

    def repository(self, name: str) -> Path:
        return self.home / "repositories" / f"{name}.git"


def new_key(path: Path) -> Path:
    """A new ed25519 key pair at ``path`` (and ``path``.pub)."""
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", path.name, "-f", str(path)], check=True)
    return path


def git_as(key: Path, known_hosts: str, *args: str, cwd=None) -> subprocess.CompletedProcess:
    """``git`` as the holder of ``key``, strict host keys."""
    ssh = f"ssh -F /dev/null -i {key} -o IdentitiesOnly=yes -o BatchMode=yes -o UserKnownHostsFile={known_hosts}"
    env = dict(
        os.environ,
        GIT_SSH_COMMAND=ssh,
        GIT_TERMINAL_PROMPT="0",
        GIT_AUTHOR_NAME="t",
        GIT_AUTHOR_EMAIL="t@x",
        GIT_COMMITTER_NAME="t",
        GIT_COMMITTER_EMAIL="t@x",
    )
    return subprocess.run(["git", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=60)
