"""The ROS 1 preset's rendered compose: roscore answers a health check that
asks the master, every node waits for it (first release, update, reboot),
and the nodes find the master and each other in host and bridge networking.
The end-to-end proof on real ROS: tests/e2e/test_ros.py."""

from roles.payload import presets, problems
from roles.payload.payloadctl import releases
from tests.unit.harness import fleet_problems
from tests.unit.rosfleet import NODES, REG, ROS1, rendered

WAIT = {"roscore": {"condition": "service_healthy", "restart": True}}


def test_roscore_is_healthy_when_its_master_answers_and_every_node_waits_for_that():
    doc = rendered({"payload_services": NODES, **ROS1})
    assert list(doc["services"]) == ["roscore", "talker", "listener"]
    roscore = doc["services"]["roscore"]
    assert roscore["command"] == ["roscore"] and "depends_on" not in roscore
    check = roscore["healthcheck"]
    assert check["test"][:3] == ["CMD", "python3", "-c"] and "getSystemState" in check["test"][3]
    assert check["start_interval"] == "1s" and check["start_period"] == "60s"
    for name in ("talker", "listener"):
        assert doc["services"][name]["depends_on"] == WAIT
    assert problems.schema_problems(doc) == []


def test_host_networking_reaches_the_master_on_localhost_and_names_nodes_by_the_host_address():
    doc = rendered({"payload_services": NODES, **ROS1})
    for name in ("roscore", "talker", "listener"):
        service = doc["services"][name]
        assert service["network_mode"] == "host"
        assert service["environment"]["ROS_MASTER_URI"] == "http://localhost:11311"
        assert service["environment"]["ROS_HOSTNAME"] == "10.0.0.9"
        assert "ROS_DOMAIN_ID" not in service["environment"]


def test_bridge_networking_puts_the_graph_on_the_project_network_named_by_service():
    doc = rendered({"payload_services": NODES, **ROS1, "payload_network_mode": "bridge"})
    for name in ("roscore", "talker", "listener"):
        service = doc["services"][name]
        # Docker's default bridge has no names: the project's own network resolves `roscore`.
        assert "network_mode" not in service
        assert service["environment"]["ROS_MASTER_URI"] == "http://roscore:11311"
        assert service["environment"]["ROS_HOSTNAME"] == name
    assert problems.schema_problems(doc) == []


def test_a_service_s_own_keys_win_and_its_own_dependencies_are_kept():
    nodes = {
        "talker": {**NODES["talker"], "depends_on": ["driver"], "network_mode": "host"},
        "driver": {"image": f"{REG}/ros/driver:1.0", "environment": {"ROS_HOSTNAME": "drv"}},
    }
    doc = rendered({"payload_services": nodes, **ROS1, "payload_network_mode": "bridge"})
    assert doc["services"]["talker"]["depends_on"] == {"driver": {"condition": "service_started"}, **WAIT}
    assert doc["services"]["talker"]["network_mode"] == "host"
    assert doc["services"]["driver"]["environment"]["ROS_HOSTNAME"] == "drv"


def test_an_explicit_ros_hostname_wins_in_either_network():
    for mode in ("host", "bridge"):
        doc = rendered({"payload_services": NODES, **ROS1, "payload_network_mode": mode, "ros_hostname": "r7"})
        assert {s["environment"]["ROS_HOSTNAME"] for s in doc["services"].values()} == {"r7"}


def test_without_roscore_nothing_waits_and_no_health_check_is_added():
    doc = rendered({"payload_services": NODES, "ros_preset": "ros1", "ros_master_uri": "http://master:11311"})
    assert all("depends_on" not in s and "healthcheck" not in s for s in doc["services"].values())


def test_engines_older_than_25_get_the_check_without_start_interval():
    doc = rendered({"payload_services": NODES, **ROS1})
    old = releases.for_engine(doc, "24.0.7")
    assert "start_interval" not in old["services"]["roscore"]["healthcheck"]
    assert old["services"]["roscore"]["healthcheck"]["interval"] == presets.ROSCORE_HEALTHCHECK["interval"]
    assert "start_interval" in doc["services"]["roscore"]["healthcheck"]  # the input is left alone
    for version in ("25.0.0", "26.1.5+dfsg1", "28.5.2", None):
        assert releases.for_engine(doc, version) == doc


def test_the_guide_s_fleet_file_is_accepted_and_orders_its_graph():
    from tests.lab.ros_graph import guide_vars  # the block tests/e2e/test_ros.py and the demo deploy

    graph = guide_vars("reg.example.com/")
    assert fleet_problems({"robots": {"vars": graph, "hosts": {"robot3": {"address": "10.0.0.3"}}}}) == []
    doc = rendered(graph)
    assert list(doc["services"]) == ["roscore", "talker", "listener"]
    assert all(doc["services"][name]["depends_on"] == WAIT for name in ("talker", "listener"))
