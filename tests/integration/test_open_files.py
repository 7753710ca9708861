"""robotfleet/limits.py: the open-file limit raised to what a run needs,
in a child process whose limits the test sets; the collector run less often
by every process that loads an inventory."""

import json
import resource
import subprocess
import sys

import pytest

from robotfleet import limits

CHILD = """
import json, resource, sys
from robotfleet import limits
resource.setrlimit(resource.RLIMIT_NOFILE, (int(sys.argv[1]), int(sys.argv[2])))
line = limits.raise_open_files(int(sys.argv[3]))
print(json.dumps({"soft": resource.getrlimit(resource.RLIMIT_NOFILE)[0], "line": line}))
"""


def child(soft: int, hard: int, hosts: int) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(soft), str(hard), str(hosts)], capture_output=True, text=True, check=True
    ).stdout
    return json.loads(out)


@pytest.fixture(autouse=True)
def hard_enough():
    if resource.getrlimit(resource.RLIMIT_NOFILE)[1] < 4000:
        pytest.skip("needs a hard limit of at least 4000 here")


def test_the_soft_limit_rises_to_what_the_hosts_need():
    assert child(1024, 4000, 1000) == {"soft": limits.needed(1000), "line": None}
    assert limits.needed(1000) == 3064


def test_it_is_never_lowered():
    assert child(3500, 4000, 10) == {"soft": 3500, "line": None}


def test_a_hard_limit_too_low_is_one_line_and_the_soft_limit_goes_to_it():
    found = child(256, 1024, 1000)
    assert found["soft"] == 1024
    assert found["line"] == (
        "1000 hosts need about 3064 open files and this process may have at most 1024 "
        "(ulimit -Hn): raise the hard limit (limits.conf, systemd's LimitNOFILE) or run fewer "
        "hosts at once (--limit a group, robotfleet rollout)"
    )


def test_an_inventory_run_collects_garbage_less_often(tmp_path):
    from tests.fixtures import ROOT
    from tests.integration.operator_side import fleet

    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1"}})
    script = (
        "import gc, json; from pyinfra.api import State; from pyinfra.context import ctx_state; "
        "from pyinfra_cli.inventory import make_inventory\n"
        "before = gc.get_threshold()\n"
        "with ctx_state.use(State()): make_inventory('inventories/robots.py')\n"
        "print(json.dumps([before, gc.get_threshold()]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(path), "HOME": str(tmp_path)},
    ).stdout
    before, after = json.loads(out)
    assert after == [max(before[0], limits.COLLECT_EVERY), *before[1:]] and after != before
