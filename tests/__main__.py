"""The test command (README, .ci/run): the three layers, the end-to-end one
beside the other two.

    .venv/bin/python -m tests [PYTEST OPTIONS]

The end-to-end layer spends most of its time waiting on its simulated
hosts (their apt, Docker and systemd), and the unit and integration layers
need no host, so they run at the same time, as two pytest processes: the
end-to-end output streams here, the other layers' output follows when they
are done.  The exit code is pytest's for the first layer that failed (0 when
both passed; a layer whose tests the options leave out does not count).
Options are handed to both (e.g. -x, -k, -p no:cacheprovider).

One layer alone: .venv/bin/python -m pytest tests/unit (or tests/integration,
tests/e2e); all three one after the other: .venv/bin/python -m pytest.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LOCAL_LAYERS = ["tests/unit", "tests/integration"]
E2E_LAYER = ["tests/e2e"]


def pytest(paths: list[str], options: list[str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pytest", *paths, *options], cwd=ROOT, **kwargs)


def main(argv: list[str]) -> int:
    started = time.monotonic()
    with tempfile.TemporaryFile(mode="w+", prefix="tests-local-") as local_log:
        local = pytest(LOCAL_LAYERS, argv, stdout=local_log, stderr=subprocess.STDOUT, text=True)
        e2e = pytest(E2E_LAYER, argv)
        try:
            e2e_code = e2e.wait()
            local_code = local.wait()
        except KeyboardInterrupt:
            for process in (local, e2e):
                process.terminate()
            for process in (local, e2e):
                process.wait()
            raise
        local_log.seek(0)
        print(f"\n===== {' and '.join(LOCAL_LAYERS)} (run beside the end-to-end layer) =====", flush=True)
        sys.stdout.write(local_log.read())
    minutes, seconds = divmod(round(time.monotonic() - started), 60)
    print(f"\n===== tests: unit and integration exit {local_code}, end to end exit {e2e_code}, "
          f"{minutes} min {seconds} s in all =====", flush=True)
    # 5 is pytest's "no tests collected": options that select one layer's tests only.
    ran = [code for code in (local_code, e2e_code) if code != 5] or [5]
    return next((code for code in ran if code), 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
