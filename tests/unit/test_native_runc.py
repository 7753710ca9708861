"""The lab's native runc for the emulated arm64 hosts (tests/lab/native_runc.py):
what it copies where, without a Docker engine."""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

from tests.lab import native_runc


def test_the_archive_puts_runc_and_its_amd64_libraries_where_an_amd64_system_has_them(tmp_path):
    for _, _, target in native_runc.FILES:
        (tmp_path / target).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / target).write_bytes(target.encode())
    with tarfile.open(fileobj=io.BytesIO(native_runc.archive(tmp_path))) as tar:
        members = {m.name: m for m in tar.getmembers()}
        assert tar.extractfile(members["usr/local/lib/robot-lab/runc"]).read() == b"usr/local/lib/robot-lab/runc"
    assert sorted(members) == [
        "lib64",
        "usr/lib/x86_64-linux-gnu/ld-linux-x86-64.so.2",
        "usr/lib/x86_64-linux-gnu/libc.so.6",
        "usr/lib/x86_64-linux-gnu/libseccomp.so.2",
        "usr/lib64/ld-linux-x86-64.so.2",
        "usr/local/lib/robot-lab/runc",
    ]
    assert members["usr/local/lib/robot-lab/runc"].mode == 0o755
    # runc's ELF interpreter is /lib64/ld-linux-x86-64.so.2: lib64 -> usr/lib64 -> the loader.
    assert (members["lib64"].issym(), members["lib64"].linkname) == (True, "usr/lib64")
    assert members["usr/lib64/ld-linux-x86-64.so.2"].linkname == "../lib/x86_64-linux-gnu/ld-linux-x86-64.so.2"


def test_the_runtime_lab_yaml_names_is_the_one_copied():
    text = (Path(__file__).resolve().parents[2] / "inventories" / "lab.yaml").read_text()
    assert f"runtimes: {{{native_runc.RUNTIME}: {{path: {native_runc.RUNC}}}}}" in text
    assert f"default-runtime: {native_runc.RUNTIME}" in text
