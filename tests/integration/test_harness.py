"""What tests/unit/test_harness.py cannot see in its own process: importing
the status module in a fresh interpreter patches nothing (pyinfra's gevent
patches only where pyinfra runs)."""

import subprocess
import sys


def test_importing_the_status_module_patches_nothing():
    code = (
        "import robotfleet.commands.status, gevent.monkey as m; "
        "print(m.is_module_patched('socket'), m.is_module_patched('ssl'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
