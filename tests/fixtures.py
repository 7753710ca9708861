"""Helpers more than one test module needs, written once for every layer
(unit, integration, end to end).  Nothing here starts a process at import;
the helpers that run one (``sh``, ``run_command``) are for the integration
and end-to-end layers."""

from __future__ import annotations

import grp
import io
import os
import pwd
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def gevent_os_patched():
    """gevent.monkey when it has patched this process's os module (pyinfra's
    CLI imported: ``os.close`` of a directory or pipe waits for gevent's
    loop, tests/conftest.py), else None."""
    monkey = sys.modules.get("gevent.monkey")
    return monkey if monkey is not None and monkey.is_module_patched("os") else None


def pyinfra_after(setup: str) -> str:
    """pyinfra's command line for `python -c`, run after ``setup`` (Python code
    of the same process: counters on the connector, the unit harness's
    recorder) in the same process; the arguments after the code are pyinfra's."""
    return f"import sys\n{setup}\nfrom pyinfra_cli.main import main\nsys.argv[0] = 'pyinfra'\nmain()\n"


# pyinfra's command line as `python -c PYINFRA ...`: the CLI of the pyinfra
# this interpreter imports, whatever is first on PATH.  Every test and
# benchmark starts pyinfra through pyinfra_argv, pyinfra or start_pyinfra.
PYINFRA = pyinfra_after("")


def pyinfra_argv(*args: str, python: str = sys.executable, setup: str = "") -> list[str]:
    """The command line of ``pyinfra *args`` run by ``python``, after ``setup`` (pyinfra_after)."""
    return [str(python), "-c", pyinfra_after(setup), *args]


def pyinfra(*args: str, cwd=ROOT, env: dict | None = None, timeout: float = 120, setup: str = "", **kwargs):
    """``pyinfra *args`` run to its end in ``cwd`` (the checkout), after
    ``setup`` (pyinfra_after): a CompletedProcess, its output as text unless
    ``kwargs`` say otherwise.  ``env`` is the whole environment (None: this
    process's)."""
    options = {"capture_output": True, "text": True, **kwargs}
    return subprocess.run(pyinfra_argv(*args, setup=setup), cwd=cwd, env=env, timeout=timeout, **options)


def start_pyinfra(*args: str, cwd=ROOT, env: dict | None = None, **kwargs) -> subprocess.Popen:
    """``pyinfra *args`` started in ``cwd`` and left running (Popen's ``kwargs``)."""
    return subprocess.Popen(pyinfra_argv(*args), cwd=cwd, env=env, **kwargs)


IMAGE = "reg.example.com/ros/payload:1.0"
GOOD_HOST = {"address": "10.0.0.3", "payload_image": IMAGE}  # a robot that needs no other setting


def robot_fleet(**settings) -> dict:
    """A fleet document of one robot, robot3 at 10.0.0.3, with ``settings``."""
    return {"robots": {"hosts": {"robot3": {"address": GOOD_HOST["address"], **settings}}}}


def good_robot(**settings) -> dict:
    """The fleet of one robot that needs no other setting, with ``settings``."""
    return robot_fleet(**{**GOOD_HOST, **settings})


def me() -> tuple[str, str]:
    """This process's user and group names (what a written file may be owned by here)."""
    return pwd.getpwuid(os.getuid()).pw_name, grp.getgrgid(os.getgid()).gr_name


def sh(script: str, **kwargs) -> subprocess.CompletedProcess:
    """A generated shell script run by this machine's sh, as a robot's would."""
    options = {"capture_output": True, "text": True, "timeout": 60, **kwargs}
    return subprocess.run(["sh", "-c", script], **options)


class _Kept(io.BytesIO):
    def close(self) -> None:  # pyinfra's writer closes what it wrote to; keep the bytes
        pass


def stdin_bytes(stdin) -> bytes:
    """What pyinfra's own writer sends as a command's stdin."""
    from pyinfra.connectors.util import write_stdin

    buffer = _Kept()
    write_stdin(stdin, buffer)
    return buffer.getvalue()


def run_command(command, **kwargs) -> subprocess.CompletedProcess:
    """A pyinfra command (``StringCommand``) run by sh here, with the stdin
    pyinfra would send it; stdout and stderr as text."""
    arguments = getattr(command, "connector_arguments", None) or {}
    stdin = arguments.get("_stdin")
    proc = subprocess.run(
        ["sh", "-c", command.get_raw_value()],
        input=stdin_bytes(stdin) if stdin else b"",
        capture_output=True,
        **{"timeout": 60, **kwargs},
    )
    return subprocess.CompletedProcess(
        proc.args, proc.returncode, proc.stdout.decode(errors="replace"), proc.stderr.decode(errors="replace")
    )
