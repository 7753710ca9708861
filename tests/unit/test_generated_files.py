"""The files a fresh robot is sent, compared byte for byte with reviewed
copies in tests/unit/golden/ (the payload unit is checked by systemd itself
in tests/integration/test_generated_files.py).

The converged-host tests build their snapshots with the production
renderers, so they prove consistency only; these prove content.  After an
intended change, regenerate and review the diff:

    ROBOT_REGENERATE_GOLDEN=1 python3 -m pytest tests/unit/test_generated_files.py
"""

import os
from pathlib import Path

import pytest

from tests.unit.samples import UNIT

GOLDEN = Path(__file__).resolve().parent / "golden"
REGENERATE = os.environ.get("ROBOT_REGENERATE_GOLDEN") == "1"


@pytest.mark.parametrize(
    "golden, sent",
    [
        ("daemon.json", "/etc/docker/daemon.json"),
        ("robot-payload.service", UNIT),
        ("70-robot-sensors.rules", "/etc/udev/rules.d/70-robot-sensors.rules"),
        ("compose.yaml", "compose.yaml"),
    ],
)
def test_sent_file_matches_its_golden_copy(sent_to_a_fresh_robot, golden, sent):
    content = sent_to_a_fresh_robot[sent]
    path = GOLDEN / golden
    if REGENERATE:
        path.write_text(content)
    assert content == path.read_text(), (
        f"{sent} differs from tests/unit/golden/{golden} (ROBOT_REGENERATE_GOLDEN=1 to accept)"
    )
