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


def test_the_arm64_recipe_adds_its_architecture_and_leaves_amd64s_alone(hostimage):
    assert "arch" not in hostimage.base_recipe()  # every machine's cached amd64 image stays valid
    assert hostimage.base_recipe("arm64")["arch"] == "arm64"
    assert hostimage.base_tag("arm64") != hostimage.base_tag() and hostimage.host_tag("arm64") != hostimage.host_tag()
    assert hostimage.host_recipe()["files"] == hostimage.HOST_FILES
    emulated = hostimage.host_recipe("arm64")["files"]
    assert emulated["etc/docker/daemon.json"] == '{"iptables": false}\n'
    assert "ImportCredential=" in emulated["etc/systemd/system/service.d/10-robot-lab-qemu-user.conf"]
    assert "systemctl mask user@.service" in hostimage.host_recipe("arm64")["script"]
    assert hostimage.host_recipe()["script"] == hostimage.CUSTOMISE_SCRIPT


def test_an_unknown_architecture_is_one_error(hostimage, engine):
    import pytest

    with pytest.raises(engine.LabError, match="no lab host image for architecture 'riscv64'"):
        hostimage.base_recipe("riscv64")


def test_a_foreign_rootfs_names_its_architecture_and_the_native_one_does_not(hostimage):
    native = hostimage.mmdebstrap_command("-")
    assert native[:2] == ["mmdebstrap", "--mode=root"] and not any(a.startswith("--arch") for a in native)
    assert native[-3:-1] == [hostimage.SUITE, "-"]
    foreign = hostimage.mmdebstrap_command("/t/layer.tar", "arm64")
    assert "--arch=arm64" in foreign and foreign[-3:-1] == [hostimage.SUITE, "/t/layer.tar"]


def test_a_foreign_base_image_says_its_architecture(hostimage, tmp_path):
    import json
    import tarfile

    layer = tmp_path / "layer.tar"
    with tarfile.open(layer, "w") as tar:
        tar.add(__file__, "etc/hostname")
    hostimage.rootfs_image_archive(layer, "robot-lab-base:x", "arm64", tmp_path / "image.tar")
    with tarfile.open(tmp_path / "image.tar") as archive:
        manifest = json.load(archive.extractfile("manifest.json"))[0]
        config = json.load(archive.extractfile(manifest["Config"]))
        assert manifest["RepoTags"] == ["robot-lab-base:x"] and manifest["Layers"] == ["rootfs/layer.tar"]
        assert archive.extractfile("rootfs/layer.tar").read() == layer.read_bytes()
    assert (config["architecture"], config["os"], config["variant"]) == ("arm64", "linux", "v8")
    import hashlib

    assert config["rootfs"]["diff_ids"] == ["sha256:" + hashlib.sha256(layer.read_bytes()).hexdigest()]
