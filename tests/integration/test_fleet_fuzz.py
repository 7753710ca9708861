"""The generated fleets of tests/unit/test_fleet_fuzz.py through pyinfra's
real CLI: refused ones exit 2 with the same problem lines and contact no
host; an accepted control fleet does connect (to a listener here)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from robotfleet.fleet import yaml12
from tests.fixtures import start_pyinfra
from tests.integration import sshserver
from tests.unit.fleetfuzz import SHOWN, documents, good_fleet, outcome


def run_cli(paths: list[Path]) -> list[subprocess.CompletedProcess]:
    """The real `pyinfra -y inventories/robots.py deploy.py`, the fleet file
    chosen by $ROBOT_FLEET, several at once.  (Each costs seconds of pyinfra
    start-up; the in-process test above covers the many documents.)"""
    procs = [
        start_pyinfra(
            "-y",
            "inventories/robots.py",
            "deploy.py",
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
            env={
                "PATH": "/usr/bin:/bin",
                "ROBOT_FLEET": str(path),
                "PYINFRA_PROGRESS": "off",
                "HOME": str(path.parent),
            },
        )
        for path in paths
    ]
    results = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        results.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    return results


def test_cli_refuses_generated_fleets_before_any_connection(tmp_path):
    listener, control_listener = sshserver.Listener(hang_up=True), sshserver.Listener(hang_up=True)
    try:
        yaml_level, check_level = [], []
        for label, data in documents(listener.port, 200, seed=3):
            lines = outcome(data)
            kind = check_level if lines is None or ": YAML error: " not in lines[0] else yaml_level
            if lines is not None and not kind:
                kind.append((label, data, lines))
        refused = yaml_level + check_level
        assert len(refused) == 2
        paths = []
        for index, (_, data, _) in enumerate(refused):
            paths.append(tmp_path / f"refused{index}" / SHOWN)
            paths[-1].parent.mkdir()
            paths[-1].write_bytes(data)
        # The control: an accepted fleet pointed at another listener does
        # connect, so the zero below is not an artefact of the listener.
        control = tmp_path / "accepted" / SHOWN
        control.parent.mkdir()
        one_host = good_fleet(control_listener.port)
        del one_host["laptops"], one_host["robots"]["hosts"]["r1"], one_host["robots"]["hosts"]["r2"]
        control.write_text(yaml12.dump(one_host))

        *results, control_result = run_cli(paths + [control])
        for (label, _, lines), result in zip(refused, results):
            output = result.stdout + result.stderr
            assert result.returncode == 2, f"{label}: exit {result.returncode}\n{output}"
            assert "Traceback" not in output, f"{label}\n{output}"
            ours = [line for line in result.stderr.splitlines() if not line.startswith("--> ")]
            assert ours[-1] == f"{len(lines)} problem(s) in the fleet file; no host was contacted.", output
            assert [line.rsplit(SHOWN + ": ", 1)[-1] for line in ours[:-1]] == [
                line.split(": ", 1)[1] for line in lines
            ]
        assert listener.connections == 0
        assert control_result.returncode != 2 and control_listener.connections > 0
    finally:
        listener.close()
        control_listener.close()
