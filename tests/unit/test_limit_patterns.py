"""Ansible's --limit habits (issue 39, item 5): ``all`` is every host, and a
subscript (``robots[0:2]``) is Ansible's: those of the hosts a pattern
matches, counted from 0, both ends in; never a glob's character class.
What cannot select is refused in one line saying what the subscript means.
(tests/integration/test_limits.py has Ansible itself select the same.)"""

from __future__ import annotations

import pytest

from robotfleet import selection

HOSTS = [(f"robot0{i}", {"robots"}) for i in range(1, 6)] + [("lap1", {"laptops"})]
GROUPS = {"robots", "laptops"}


@pytest.mark.parametrize(
    "limit, chosen",
    [
        ("all", ["robot01", "robot02", "robot03", "robot04", "robot05", "lap1"]),
        ("all,!robot04", ["robot01", "robot02", "robot03", "robot05", "lap1"]),
        ("all,&robots,!robot0[1-3]", ["robot04", "robot05"]),  # [1-3]: pyinfra's glob, as documented
        ("robots[0]", ["robot01"]),
        ("robots[1]", ["robot02"]),
        ("robots[-1]", ["robot05"]),
        ("robots[0:2]", ["robot01", "robot02", "robot03"]),
        ("robots[3:]", ["robot04", "robot05"]),
        ("robots[0:0]", ["robot01"]),
        ("robot*[1:2]", ["robot02", "robot03"]),
        ("all,!robots[0:3]", ["robot05", "lap1"]),
    ],
)
def test_all_and_subscripts_select_as_ansible_does(limit, chosen):
    assert selection.refusal([limit], "inv.py", HOSTS, GROUPS) is None
    assert selection.resolve([limit], HOSTS, GROUPS)[0] == chosen


def test_a_subscript_is_never_a_character_class():
    """robot0[1:3] was a glob matching robot01 and robot03: now Ansible's
    subscript of robot0's hosts (none), refused in one line that says so."""
    assert selection.resolve(["robot0[1:3]"], HOSTS, GROUPS)[0] == []
    line = selection.refusal(["robot0[1:3]"], "inv.py", HOSTS, GROUPS)
    assert line.startswith(
        "--limit robot0[1:3]: [1:3] is Ansible's subscript of the hosts robot0 matches (counted "
        "from 0), and no host or group of inv.py matches robot0; for host names in a range write "
        "a glob (robot0[1-3], robot0*) or a comma list (hosts: robot01, "
    ), line
    assert line.endswith("nothing was done") and "\n" not in line


@pytest.mark.parametrize(
    "limit, start",
    [
        (
            "robots[9]",
            "--limit robots[9]: robots matches 5 host(s), robots[0] to robots[4]; [9] is Ansible's subscript "
            "of them, counted from 0 (hosts: ",
        ),
        (
            "robots[2:1]",
            "--limit robots[2:1]: a subscript [begin:end] needs begin <= end (both counted, from 0); nothing was done",
        ),
        ("robots:laptops[0:1]", "--limit robots:laptops[0:1]: separate patterns with commas (robots,laptops), not ':'"),
    ],
)
def test_a_subscript_that_cannot_select_is_refused_in_one_line(limit, start):
    assert selection.refusal([limit], "inv.py", HOSTS, GROUPS).startswith(start)


@pytest.mark.parametrize(
    "limit, named", [("all", False), ("robot0[1-3]", False), ("robots[0:2]", True), ("all,!robot04", True)]
)
def test_pyinfra_gets_a_group_for_what_its_own_limit_reads_otherwise(limit, named):
    """pyinfra reads all (its inventories have that group) and globs itself;
    a subscript it would read as a glob is handed to it as a group."""
    assert selection.needs_group(limit) is named
