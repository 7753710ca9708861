"""The end-to-end lab groups of the test command (tests/e2e/groups.py) and
its exit code (tests/__main__.py)."""

import time

from tests.__main__ import exit_code, local_paths, machine_seconds
from tests.e2e import groups


def test_every_module_the_groups_name_exists_and_is_in_one_group_only():
    named = [module for modules in groups.GROUPS.values() for module in modules]
    assert len(named) == len(set(named)), named
    assert set(named) <= set(groups.modules()), set(named) - set(groups.modules())


def test_a_module_no_group_names_runs_in_the_default_group():
    plan = groups.plan(["test_pull.py", "test_a_new_module.py", "test_ros.py", "test_fleet.py"])
    assert plan == {
        groups.DEFAULT_GROUP: ["test_a_new_module.py", "test_fleet.py"],
        "pull": ["test_pull.py"],
        "hosts": ["test_ros.py"],
    }
    assert groups.group_of("test_pull_over_something_new.py") == groups.DEFAULT_GROUP


def test_the_plan_has_every_module_once_and_no_empty_group():
    plan = groups.plan(groups.modules())
    assert sorted(m for modules in plan.values() for m in modules) == groups.modules()
    assert all(plan.values())
    assert groups.plan(["test_fleet.py"]) == {groups.DEFAULT_GROUP: ["test_fleet.py"]}


def test_the_exit_code_is_the_first_failing_process_s():
    assert exit_code([0, 0, 0, 0]) == 0
    assert exit_code([0, 1, 2, 0]) == 1
    assert exit_code([2, 1, 0, 0]) == 2
    assert exit_code([5, 0, 1, 5]) == 1  # a process the options left without tests does not count
    assert exit_code([5, 0, 5, 5]) == 0
    assert exit_code([5, 5, 5, 5]) == 5


def test_the_modules_that_need_no_lab_run_after_unit_and_integration(tmp_path):
    for name in ("test_a.py", "test_b.py", "test_c.py", "helper.py"):
        (tmp_path / "tests/integration").mkdir(parents=True, exist_ok=True)
        (tmp_path / "tests/integration" / name).write_text("")
    plan = groups.plan(["test_fleet.py", "test_laptop_sudo.py", "test_stock_machine.py"])
    assert plan[groups.WITH_UNIT] == ["test_laptop_sudo.py", "test_stock_machine.py"]
    assert local_paths(plan, tmp_path) == (
        ["tests/unit", "tests/integration/test_a.py", "tests/integration/test_c.py"],
        ["tests/integration/test_b.py", "tests/e2e/test_laptop_sudo.py", "tests/e2e/test_stock_machine.py"],
    )
    assert local_paths(groups.plan(["test_fleet.py"]), tmp_path)[1] == ["tests/integration/test_b.py"]


def test_the_on_demand_modules_exist_and_are_not_in_the_test_command():
    assert set(groups.ON_DEMAND) <= {path.name for path in groups.E2E_DIR.glob("test_*.py")}
    assert not set(groups.ON_DEMAND) & set(groups.modules())
    named = {module for modules in groups.GROUPS.values() for module in modules}
    assert not set(groups.ON_DEMAND) & named


def test_the_machine_s_busy_seconds_count_what_this_process_spends():
    busy, idle = machine_seconds()
    spin_until = time.process_time() + 0.3
    while time.process_time() < spin_until:
        pass
    busy_after, idle_after = machine_seconds()
    assert busy_after - busy >= 0.25 and idle_after >= idle
