"""An Ansible YAML inventory works as it is (issue 18, item 6): children
groups at any depth, settings merged from every group above a host, Ansible's
connection variables read as ours, Ansible's other variables ignored with a
note; robots and laptops (at any depth) say which host is which."""

from tests.fixtures import ROOT
from tests.unit.harness import fleet_problems, parse

IMAGE = "reg.example.com/p:1"

ANSIBLE = f"""
all:
  vars:
    ansible_user: ops
    ansible_become: true
    ansible_python_interpreter: /usr/bin/python3
    payload_image: {IMAGE}
    ros_domain_id: 1
  children:
    robots:
      vars:
        ros_domain_id: 2
        docker_users: [ops]
      children:
        site_a:
          vars: {{ros_domain_id: 3, payload_stable_seconds: 7}}
          children:
            row_1:
              vars: {{ros_domain_id: 4}}
              hosts:
                robot7:
                  ansible_host: 10.20.1.7
                  ansible_port: 2222
                  ansible_ssh_private_key_file: ~/.ssh/fleet_ed25519
        site_b:
          hosts:
            robot8: {{ansible_host: 10.20.2.8, ros_domain_id: 9}}
    laptops:
      hosts:
        alice-laptop: {{ansible_host: 10.20.0.50, ansible_user: alice, x11_user: alice}}
"""


def test_nested_children_merge_from_every_group_above_a_host():
    fleet = parse(ANSIBLE)
    robots = dict(fleet.hosts("robots"))
    assert list(robots) == ["robot7", "robot8"]
    robot7 = robots["robot7"]
    # the deepest group wins over the groups above it; every group adds its own
    assert robot7["ros_domain_id"] == 4 and robot7["payload_stable_seconds"] == 7
    assert robot7["docker_users"] == ["ops"]
    assert robots["robot8"]["ros_domain_id"] == 9  # the host wins over its groups
    assert fleet.subgroups == {"site_a": ["robot7"], "row_1": ["robot7"], "site_b": ["robot8"]}


def test_ansible_connection_variables_are_read_as_ours():
    fleet = parse(ANSIBLE)
    robot7 = dict(fleet.hosts("robots"))["robot7"]
    assert (robot7["ssh_hostname"], robot7["ssh_port"], robot7["ssh_key"], robot7["ssh_user"]) == (
        "10.20.1.7",
        2222,
        "~/.ssh/fleet_ed25519",
        "ops",
    )
    assert not any(key.startswith("ansible_") for key in robot7)
    alice = dict(fleet.hosts("laptops"))["alice-laptop"]
    assert (alice["ssh_hostname"], alice["ssh_user"]) == ("10.20.0.50", "alice")  # the host's user wins over all's


def test_ansible_own_variables_are_ignored_with_one_note():
    fleet = parse(ANSIBLE)
    assert fleet.notes == ["f.yaml: note: ansible_become, ansible_python_interpreter: Ansible's own, ignored here"]


def test_kinds_stay_explicit_at_any_depth():
    both = {
        "all": {
            "children": {
                "robots": {"children": {"site": {"hosts": {"r1": {"payload_image": IMAGE}}}}},
                "laptops": {"children": {"desk": {"children": {"site": None}}}},
            }
        }
    }
    assert fleet_problems(both) == ["robots.yaml: r1: declared in both robots and laptops"]
    neither = {"all": {"children": {"site": {"hosts": {"r1": {"payload_image": IMAGE}}}}}}
    assert fleet_problems(neither) == ["robots.yaml: r1: in neither a robots nor a laptops group (groups: site)"]


def test_mistakes_in_nested_groups_name_the_group_and_field():
    doc = {
        "robots": {
            "children": {
                "site_a": {"vars": {"ssh_prot": 22}, "host": {}},
                "site_b": {"hosts": {"r1": {"payload_image": IMAGE, "ansible_port": "22"}}},
            }
        }
    }
    assert fleet_problems(doc) == [
        "robots.yaml: site_a.host: unknown key (did you mean 'hosts'?); a group has vars, hosts and children",
        "robots.yaml: site_a.vars.ssh_prot: unknown setting (did you mean 'ssh_port'?)",
        "robots.yaml: r1.ansible_port: expected a whole number, got '22'",
    ]


def test_the_same_setting_twice_under_two_names_is_refused():
    doc = {"robots": {"hosts": {"r1": {"payload_image": IMAGE, "address": "10.0.0.1", "ansible_host": "10.0.0.2"}}}}
    assert fleet_problems(doc) == [
        "robots.yaml: r1.ansible_host: sets ssh_hostname a second time in the same place; keep one"
    ]


def test_pyinfra_sees_the_ansible_groups(tmp_path, monkeypatch, capfd):
    """--limit site_a selects that group's hosts (pyinfra's groups are the file's)."""
    from pyinfra.api import State
    from pyinfra.context import ctx_state
    from pyinfra_cli.inventory import make_inventory

    path = tmp_path / "fleet.yaml"
    path.write_text(ANSIBLE)
    monkeypatch.setenv("ROBOT_FLEET", str(path))
    monkeypatch.chdir(ROOT)
    with ctx_state.use(State()):
        inventory = make_inventory("inventories/robots.py", cwd=str(ROOT))
    assert [host.name for host in inventory.get_group("site_a")] == ["robot7"]
    assert [host.name for host in inventory.get_group("robots")] == ["robot7", "robot8"]
    assert inventory.get_host("robot7").data.ssh_port == 2222
    assert "ansible_become, ansible_python_interpreter: Ansible's own, ignored here" in capfd.readouterr().err
