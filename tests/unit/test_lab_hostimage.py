"""The lab's image recipes: hashes are stable and follow every input."""


def test_recipe_hash_is_stable_and_ignores_key_order(hostimage):
    assert hostimage.recipe_hash({"a": 1, "b": [1, 2]}) == hostimage.recipe_hash({"b": [1, 2], "a": 1})
    assert len(hostimage.recipe_hash({"a": 1})) == 12


def test_recipe_hash_changes_with_any_input(hostimage):
    base = hostimage.base_recipe()
    changed = dict(base, include=base["include"] + ["vim"])
    assert hostimage.recipe_hash(base) != hostimage.recipe_hash(changed)
    assert hostimage.recipe_hash(base) != hostimage.recipe_hash(dict(base, suite="forky"))


def test_tags_are_keyed_by_recipe(hostimage, services, monkeypatch):
    base, host, svc = hostimage.base_tag(), hostimage.host_tag(), services.services_tag()
    assert base.startswith("robot-lab-base:") and host.startswith("robot-lab-host:")
    monkeypatch.setattr(hostimage, "CUSTOMISE_SCRIPT", hostimage.CUSTOMISE_SCRIPT + "true\n")
    assert hostimage.base_tag() == base
    assert hostimage.host_tag() != host
    assert services.services_tag() != svc


def test_image_has_no_docker_and_one_package_list(hostimage):
    assert not {"docker.io", "docker-ce", "containerd"} & set(hostimage.INCLUDE_PACKAGES)
    assert {"systemd", "dbus", "openssh-server", "sudo"} <= set(hostimage.INCLUDE_PACKAGES)
    assert "rm -f /etc/ssh/ssh_host_*" in hostimage.CUSTOMISE_SCRIPT
