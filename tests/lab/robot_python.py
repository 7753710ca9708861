"""A lab host whose python3 is another release's, as on a robot of that
release: this machine's build of that Python (pyenv's, tests/pythons.py)
installed under /usr as the distribution would put it (its test suite and
IDLE left out; a venv finds its standard library from /usr/bin), and
/usr/bin/python3 pointing at it, Debian's own link set
aside with dpkg-divert (so an apt run keeps ours).  Debian's python3 stays
installed beside it, as on a robot where something else brought one.
`restore` gives the host back its own python3."""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

from .engine import LabError, client
from .state import exec_container

_LEFT_OUT = {"test", "idlelib", "tkinter", "turtledemo", "__pycache__", "site-packages"}
PYTHON3 = "/usr/bin/python3"


def _archive(prefix: Path, version: str) -> bytes:
    """bin/pythonX.Y, lib/libpythonX.Y.so.1.0 and lib/pythonX.Y (less what a robot never runs), under /usr."""
    data = io.BytesIO()
    library = prefix / "lib" / f"python{version}"

    def kept(info: tarfile.TarInfo) -> tarfile.TarInfo | None:
        return None if Path(info.name).name in _LEFT_OUT else info

    with tarfile.open(fileobj=data, mode="w") as archive:
        archive.add(prefix / "bin" / f"python{version}", arcname=f"usr/bin/python{version}")
        archive.add(prefix / "lib" / f"libpython{version}.so.1.0", arcname=f"usr/lib/libpython{version}.so.1.0")
        archive.add(library, arcname=f"usr/lib/python{version}", filter=kept)
    return data.getvalue()


def install(container_name: str, python: Path) -> str:
    """Make ``python`` (a build's bin/pythonX.Y) the host's python3; returns what it says it is."""
    version = python.name[len("python") :]
    container = client().containers.get(container_name)
    if not container.put_archive("/", _archive(python.parents[1], version)):
        raise LabError(f"{container_name}: could not copy Python {version} in")
    script = (
        f"set -e; ldconfig; dpkg-divert --local --rename --add {PYTHON3} >/dev/null; "
        f"ln -sfn python{version} {PYTHON3}; {PYTHON3} -c 'import ensurepip, ssl, venv' && "
        f"{PYTHON3} --version"
    )
    code, said = exec_container(container, ["sh", "-c", script])
    if code:
        raise LabError(f"{container_name}: Python {version} as python3: exit {code}: {said[-2000:]}")
    return said.strip()


def restore(container_name: str, version: str) -> None:
    """The host's own python3 again (Debian's), this one removed."""
    script = (
        f"set -e; rm -f {PYTHON3}; dpkg-divert --local --rename --remove {PYTHON3} >/dev/null; "
        f"rm -rf /usr/bin/python{version} /usr/lib/libpython{version}.so.1.0 /usr/lib/python{version}; "
        f"ldconfig; {PYTHON3} --version"
    )
    code, said = exec_container(client().containers.get(container_name), ["sh", "-c", script])
    if code:
        raise LabError(f"{container_name}: Debian's python3 back: exit {code}: {said[-2000:]}")
