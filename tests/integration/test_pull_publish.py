"""robotfleet publish, halt and keys end to end: a deploy repository and a
bare git remote on disk, real keys, an OCI registry answering the manifest
requests, the commands run as an operator runs them, and a robot's side
(a shallow clone of robotfleet/releases, trust.Client) checking each
result.  Wheels come from PyPI (a small requirement)."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from tests.integration.publishsite import FLEET, git, robot_fetch, robotfleet_cmd
from tests.unit import pullkit


def publish(site, *more, check=True):
    return robotfleet_cmd(
        "publish", "--checkout", site["checkout"], "--keys", site["keys"], "--no-wheels", *more, check=check
    )


def robot_refresh(site):
    trust = pullkit.module("robot.verify")
    copy = robot_fetch(site)
    state = site["robot"] / "state"
    if not state.exists():
        trust.initialize(state, (copy / "metadata" / "root.json").read_bytes())
    client = trust.Client(state, str(copy))
    return client, client.refresh()


def test_publish_binds_commit_tree_fleet_and_digests_and_a_robot_verifies_it(site, registry):
    done = publish(site)
    assert "publish: release 1 (" in done.stdout and "2 robot(s), 2 image(s) by digest" in done.stdout
    assert "pushed robotfleet/releases to" in done.stdout
    client, record = robot_refresh(site)
    assert record.version == 1
    # the plan it signed, as the robots will read it: without --pause, the waves are as far apart as the
    # robots' longest pull_interval + pull_jitter (robot2: 1000 + the default 300)
    assert record.rollout.pause == 1300
    assert "publish: 2 wave(s); wave k opens at publish + k x 1300 s" in done.stdout
    assert f"publish:   wave 0 (canary): 1 robot(s) from {record.published}: " in done.stdout
    assert record.commit == git(site["checkout"], "rev-parse", "HEAD")
    assert record.robots == ("robot1", "robot2")  # robot3 is not pull
    one = registry.manifests[("ros/payload", "1.1")][1]
    assert record.images["robot1"] == {
        f"{registry.address}/ros/payload:1.1": "sha256:" + pullkit.hashlib.sha256(one).hexdigest()
    }
    assert record.images["robot2"] == {f"{registry.address}/ros/payload:1.2": registry.tag("ros/payload", "1.2", "two")}
    got = client.download([record.code], site["robot"] / "targets")
    tree = pullkit.module("protocol.tree")
    tree.unpack(got[record.code], site["robot"] / "code")
    assert tree.tree_sha256(tree.entries_of_directory(site["robot"] / "code")) == record.tree_sha256
    fleet = (site["robot"] / "code" / record.fleet["path"]).read_bytes()
    assert pullkit.hashlib.sha256(fleet).hexdigest() == record.fleet["sha256"]
    assert not (site["robot"] / "code" / "tests").exists()
    # the branch holds only the repository, and the deploy branch is untouched
    assert sorted(os.listdir(robot_fetch(site))) == [".git", "metadata", "targets"]
    assert git(site["origin"], "rev-parse", "main") == record.commit
    assert git(site["origin"], "branch", "--list", "robotfleet/releases") == ""


def test_halt_then_a_new_release(site):
    publish(site, "--canary", "10%", "--waves", "50%,100%", "--pause", "60")
    _, first = robot_refresh(site)
    assert first.rollout.to_dict() == {"canary": "10%", "waves": ["50%", "100%"], "pause": 60, "max_failed": "0"}
    done = robotfleet_cmd(
        "halt", "--checkout", site["checkout"], "--keys", site["keys"], "--reason", "canary crash-loops"
    )
    assert done.stdout.startswith("halt: release 2 halts commit")
    _, halted = robot_refresh(site)
    assert (halted.version, halted.halt, halted.halt_reason, halted.commit) == (
        2,
        True,
        "canary crash-loops",
        first.commit,
    )
    again = robotfleet_cmd("halt", "--checkout", site["checkout"], "--keys", site["keys"], check=False)
    assert again.returncode == 2 and again.stderr == (
        "halt: release 2 is already halted (canary crash-loops); nothing was changed (a new publish ends the halt).\n"
    )
    publish(site)
    _, third = robot_refresh(site)
    assert (third.version, third.halt) == (3, False)


def test_a_dirty_tree_is_refused_unless_allowed(site):
    (site["checkout"] / "deploy.py").write_text("# changed\n")
    done = publish(site, check=False)
    assert done.returncode == 2
    assert done.stderr.startswith("publish: deploy.py: changed and not committed (1 file(s))")
    assert "or --leave-out-uncommitted to publish the commit without them" in done.stderr
    assert git(site["remote"], "branch", "--list", "robotfleet/releases") == ""
    # Issue 54, item 7: the flag says what it does, and what it left out
    head = git(site["checkout"], "rev-parse", "HEAD").strip()
    left = (
        "publish: left out of release {}, changed and not committed: deploy.py (1 file(s)); "
        f"robots get commit {head[:12]} as committed"
    )
    done = publish(site, "--leave-out-uncommitted")
    assert left.format(1) in done.stderr.splitlines(), done.stderr
    _, record = robot_refresh(site)
    assert (record.version, record.commit) == (1, head)  # the commit, not the working tree
    old = publish(site, "--allow-dirty")  # the old name still works, with a note
    assert old.stderr.splitlines() == [
        "publish: note: --allow-dirty is now --leave-out-uncommitted: a release is the commit, never the "
        "working tree's changes",
        left.format(2),
    ]


def test_an_image_the_registry_lacks_is_refused_and_nothing_is_pushed(site, registry):
    publish(site)
    before = git(site["remote"], "rev-parse", "robotfleet/releases")
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    fleet.write_text(fleet.read_text().replace("payload:1.2", "payload:9.9"))
    git(site["checkout"], "commit", "-qam", "9.9")
    done = publish(site, check=False)
    assert done.returncode == 2
    assert done.stderr.startswith(f"publish: robot2: payload: image {registry.address}/ros/payload:9.9: ")
    assert "HTTP 404" in done.stderr and len(done.stderr.splitlines()) == 1
    assert git(site["remote"], "rev-parse", "robotfleet/releases") == before


def test_a_one_part_repository_on_a_private_registry_is_published(site, registry):
    """registry.lan:5000/payload:1 is the registry's repository "payload":
    Docker adds library/ on Docker Hub only."""
    digest = registry.tag("payload", "1", "one-part")
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    fleet.write_text(fleet.read_text().replace("ros/payload:1.1", "payload:1"))
    git(site["checkout"], "commit", "-qam", "a one-part repository")
    publish(site)
    _, record = robot_refresh(site)
    assert record.images["robot1"] == {f"{registry.address}/payload:1": digest}
    assert ("GET", "/v2/payload/manifests/1") in registry.requests


def test_bad_fleet_data_in_the_commit_is_refused_with_its_lines(site):
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    fleet.write_text(fleet.read_text().replace("pull_enabled: true", "pull_enabled: yes please"))
    git(site["checkout"], "commit", "-qam", "bad")
    done = publish(site, check=False)
    assert done.returncode == 2
    assert "robots.vars.pull_enabled: expected true or false" in done.stderr
    assert "nothing was published" in done.stderr


def test_publish_without_keys_says_where_it_looked(site, tmp_path):
    done = robotfleet_cmd(
        "publish", "--checkout", site["checkout"], "--keys", tmp_path / "none", "--no-wheels", check=False
    )
    assert done.returncode == 2  # refused before anything was read or written (README's exit codes)
    assert (
        done.stderr == f"publish: {tmp_path / 'none' / 'online.key'}: no online key here "
        "(robotfleet keys init; --keys DIR or $ROBOTFLEET_KEYS)\n"
    )


def test_to_dir_is_served_over_http(site):
    out = site["base"] / "www"
    publish(site, "--to-dir", out)
    trust = pullkit.module("robot.verify")
    trust.initialize(site["robot"] / "state", (out / "metadata" / "root.json").read_bytes())
    with pullkit.static_http(out) as url:
        record = trust.Client(site["robot"] / "state", url).refresh()
    assert record.version == 1


def test_renew_re_signs_the_timestamp_only(site):
    publish(site)
    _, first = robot_refresh(site)
    done = robotfleet_cmd("publish", "--renew", "--checkout", site["checkout"], "--keys", site["keys"])
    assert done.stdout.startswith("publish: re-signed timestamp; timestamp valid until")
    _, again = robot_refresh(site)
    assert again == first
    copy = robot_fetch(site)
    assert json.loads((copy / "metadata" / "timestamp.json").read_text())["signed"]["version"] == 3


def test_keys_never_printed_and_private_files_are_0600(site):
    for name in ("root", "online"):
        key = site["keys"] / f"{name}.key"
        assert oct(key.stat().st_mode & 0o777) == "0o600"
        shown = robotfleet_cmd("keys", "show", "--checkout", site["checkout"], "--keys", site["keys"], check=False)
        assert key.read_text().splitlines()[1] not in shown.stdout + shown.stderr


def test_online_rotation_with_the_root_key_at_hand(site):
    publish(site)
    robot_refresh(site)
    done = robotfleet_cmd("keys", "rotate", "online", "--checkout", site["checkout"], "--keys", site["keys"])
    assert "root version 2 installed" in done.stdout
    assert (site["keys"] / "online.old.key").exists()
    publish(site, "--leave-out-uncommitted")
    _, record = robot_refresh(site)
    assert record.version == 2


def test_offline_root_key_prepare_sign_install(site):
    publish(site)
    robot_refresh(site)
    offline = site["base"] / "usb"
    offline.mkdir(mode=0o700)
    for suffix in (".key", ".pub"):
        shutil.move(site["keys"] / f"root{suffix}", offline / f"root{suffix}")
    refused = robotfleet_cmd(
        "keys", "rotate", "online", "--checkout", site["checkout"], "--keys", site["keys"], check=False
    )
    assert refused.returncode == 2 and "no root key here" in refused.stderr
    # a new root key made offline; the change prepared online, signed offline, installed online
    robotfleet_cmd("keys", "generate", offline / "root2.key")
    common = ("--checkout", site["checkout"], "--keys", site["keys"])
    robotfleet_cmd(
        "keys", "prepare", "root", "--out", site["base"] / "next.json", "--root-public", offline / "root2.pub", *common
    )
    unsigned = robotfleet_cmd("keys", "install", site["base"] / "next.json", *common, check=False)
    assert unsigned.returncode == 1 and "not signed by the current root key" in unsigned.stderr
    robotfleet_cmd(
        "keys", "sign", site["base"] / "next.json", "--key", offline / "root.key", "--key", offline / "root2.key"
    )
    done = robotfleet_cmd("keys", "install", site["base"] / "next.json", *common)
    assert "root version 2 installed" in done.stdout
    publish(site)
    _, record = robot_refresh(site)
    assert record.version == 2
    assert (site["robot"] / "state" / "tuf" / "root_history" / "2.root.json").exists()


def test_two_publishers_racing_one_is_refused(site):
    channel = pullkit.module("operator.channel")
    first = channel.GitChannel(site["checkout"], str(site["remote"]), clone=site["base"] / "a")
    second = channel.GitChannel(site["checkout"], str(site["remote"]), clone=site["base"] / "b")
    for chosen in (first, second):
        (chosen.open() / "metadata").mkdir(exist_ok=True)
    (first.clone / "metadata" / "x").write_text("1")
    (second.clone / "metadata" / "x").write_text("2")
    first.push("first")
    with pytest.raises(channel.ChannelError, match="moved while publishing"):
        second.push("second")
    assert git(site["remote"], "show", "robotfleet/releases:metadata/x") == "1"


def test_wheels_for_a_robot_platform_are_carried_and_verified(site):
    pyproject = site["checkout"] / "pyproject.toml"
    pyproject.write_text('[project]\nname = "x"\nversion = "1"\ndependencies = ["six==1.16.0"]\n')
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    fleet.write_text(
        fleet.read_text().replace("pull_enabled: true", "pull_enabled: true\n    pull_platform: cp311-aarch64")
    )
    git(site["checkout"], "commit", "-qam", "tiny requirements")
    cache = site["base"] / "wheels"
    robotfleet_cmd("publish", "--checkout", site["checkout"], "--keys", site["keys"], "--wheel-cache", cache)
    client, record = robot_refresh(site)
    assert record.wheels == {"cp311-aarch64": ["wheels/six-1.16.0-py2.py3-none-any.whl"]}
    got = client.download(record.wheels_for("cp311-aarch64"), site["robot"] / "targets")
    assert got["wheels/six-1.16.0-py2.py3-none-any.whl"].read_bytes()[:2] == b"PK"


def test_robots_without_pull_platform_get_the_setting_s_default_and_a_full_cache_skips_the_index(site, monkeypatch):
    """Wheels for the setting's default platform only, not for the operator's
    own Python (3.11 here: it would be a second key); and a second publish
    with every wheel cached does not ask the index (which here cannot answer)."""
    from robotfleet import deploy_roles

    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)  # only the index given here (no local mirror)
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    default = deploy_roles.registry().settings["pull_platform"].default
    pyproject = site["checkout"] / "pyproject.toml"
    pyproject.write_text('[project]\nname = "x"\nversion = "1"\ndependencies = ["six==1.16.0"]\n')
    git(site["checkout"], "commit", "-qam", "tiny requirements")
    cache = site["base"] / "wheels"
    robotfleet_cmd("publish", "--checkout", site["checkout"], "--keys", site["keys"], "--wheel-cache", cache)
    _, record = robot_refresh(site)
    assert record.wheels == {default: ["wheels/six-1.16.0-py2.py3-none-any.whl"]}
    done = robotfleet_cmd(
        "publish",
        "--checkout",
        site["checkout"],
        "--keys",
        site["keys"],
        "--wheel-cache",
        cache,
        "--index-url",
        "http://127.0.0.1:9/simple",
        "--leave-out-uncommitted",
    )
    assert "publish: release 2" in done.stdout
    refused = robotfleet_cmd(
        "publish",
        "--checkout",
        site["checkout"],
        "--keys",
        site["keys"],
        "--wheel-cache",
        cache,
        "--index-url",
        "http://127.0.0.1:9/simple",
        "--refresh-wheels",
        check=False,
    )
    assert refused.returncode != 0 and "wheels for " in refused.stderr


# --- the fleet's releases remote, named once (issue 39 item 2) ---


def test_with_no_releases_remote_named_a_pull_command_says_how_to_name_it(site, tmp_path):
    git(site["checkout"], "config", "--unset", "robotfleet.remote")
    push_only = tmp_path / "push-only.yaml"  # no pull robot: nothing names a remote
    push_only.write_text("robots:\n  hosts:\n    robot1: {address: 127.0.0.1, payload_image: 'reg/p:1'}\n")
    for argv in (["halt"], ["keys", "show"]):
        done = robotfleet_cmd(
            *argv,
            "--checkout",
            site["checkout"],
            "--keys",
            site["keys"],
            env={"ROBOT_FLEET": str(push_only)},
            check=False,
        )
        assert done.returncode == 2, done.stderr
        assert done.stderr == (
            f"{argv[0]}: no releases remote is named (no --remote, no robotfleet.remote in the "
            "checkout's git config, no pull robot with pull_remote in the fleet file); name it "
            "once: git config robotfleet.remote URL in the checkout (or pull_remote for the pull "
            "robots in the fleet file), or give --remote URL.\n"
        )
    assert git(site["origin"], "branch", "--list", "robotfleet/releases") == ""  # origin is never the default


def test_the_pull_robots_pull_remote_is_the_default(site, tmp_path):
    from tests.integration import sshserver

    git(site["checkout"], "config", "--unset", "robotfleet.remote")
    url = f"https://127.0.0.1:{sshserver.closed_port()}/fleet.git"
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(
        f"robots:\n  vars: {{pull_enabled: true, pull_remote: '{url}', payload_image: 'reg/p:1'}}\n"
        "  hosts:\n    robot1: {address: 127.0.0.1}\n"
    )
    done = robotfleet_cmd(
        "keys",
        "show",
        "--checkout",
        site["checkout"],
        "--keys",
        site["keys"],
        env={"ROBOT_FLEET": str(fleet)},
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(f"keys: cannot read the releases remote {url}: ")
    assert len(done.stderr.splitlines()) == 1
    assert done.stderr.endswith(
        "; check its URL (--remote, git config robotfleet.remote or the robots' pull_remote) "
        "and that you may read it.\n"
    )


def test_publishing_to_the_deploy_repository_s_own_remote_is_refused_unless_named(site):
    origin = str(site["origin"])
    git(site["checkout"], "config", "robotfleet.remote", origin)
    for named, given in ((origin, []), (origin, ["--remote", origin]), ("origin/", ["--remote", f"{origin}/"])):
        done = publish(site, *given, check=False)
        assert done.returncode == 2, done.stderr
        shown = f"{origin}/" if named == "origin/" else origin
        assert done.stderr == (
            f"publish: {shown} is the deploy repository's own remote (origin), and robots can read "
            "all of a remote they fetch from; keep the releases on another remote (name it once: "
            "git config robotfleet.remote URL in the checkout (or pull_remote for the pull robots "
            "in the fleet file), or give --remote URL), or give --remote origin to publish there "
            "anyway.\n"
        )
    halted = robotfleet_cmd("halt", "--checkout", site["checkout"], "--keys", site["keys"], check=False)
    assert halted.returncode == 2 and "is the deploy repository's own remote (origin)" in halted.stderr
    assert git(site["origin"], "branch", "--list", "robotfleet/releases") == ""
    done = publish(site, "--remote", "origin")  # asked for by name
    assert "pushed robotfleet/releases to" in done.stdout
    assert git(site["origin"], "branch", "--list", "robotfleet/releases").strip() == "robotfleet/releases"


def test_a_releases_remote_that_does_not_exist_is_one_sentence_naming_the_fix(site, tmp_path):
    missing = tmp_path / "nonexistent.git"
    done = publish(site, "--remote", missing, check=False)
    assert done.returncode == 1
    assert done.stderr == (
        f"publish: cannot read the releases remote {missing}: '{missing}' does not appear to be a "
        "git repository; check its URL (--remote, git config robotfleet.remote or the robots' "
        "pull_remote) and that you may read it.\n"
    )


def test_halting_before_any_release_is_refused_in_one_sentence(site):
    done = robotfleet_cmd("halt", "--checkout", site["checkout"], "--keys", site["keys"], check=False)
    assert done.returncode == 2
    assert done.stderr.startswith("halt: ") and done.stderr.endswith(
        ": no release to halt; there is nothing for robots to stop.\n"
    )
    assert git(site["remote"], "branch", "--list", "robotfleet/releases") == ""


# -- a secret in the fleet file never travels (issue 50, item 3) ----------------

REFUSED_TOKEN = (
    "inventories/robots.yaml: robot1.payload_environment.API_TOKEN holds a secret ({more}), and the fleet file "
    "travels in every release to every robot and mirror: keep it out of the fleet file (payload_secret_files, or "
    "an _env/_file form such as payload_registry_auths' password_file); nothing was {done}"
)


def with_secrets(site) -> None:
    """A token in a pull robot's environment and a proxy's password on a push-only robot, committed."""
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    text = fleet.read_text()
    text = text.replace(
        "robot1: {address: 127.0.0.1}", "robot1: {address: 127.0.0.1, payload_environment: {API_TOKEN: tok-77c1}}"
    )
    text = text.replace(
        "pull_enabled: false}",
        "pull_enabled: false, docker_daemon_options: {proxies: {http-proxy: 'http://op:pr0xy@proxy.lan:3128'}}}",
    )
    fleet.write_text(text)
    git(site["checkout"], "commit", "-qam", "secrets in the fleet file")


def test_a_fleet_file_holding_a_secret_is_refused_in_one_line_naming_host_and_field(site, registry):
    with_secrets(site)
    done = publish(site, check=False)
    assert done.returncode == 2
    assert done.stderr == "publish: " + REFUSED_TOKEN.format(more="1 more in the file", done="published") + "\n"
    assert "tok-77c1" not in done.stderr + done.stdout and "pr0xy" not in done.stderr + done.stdout
    assert git(site["remote"], "branch", "--list", "robotfleet/releases") == ""
    # a path to the secret's file is no secret: the release goes out
    fleet = site["checkout"] / "inventories" / "robots.yaml"
    fleet.write_text(
        FLEET.format(registry=registry.address).replace(
            "robot1: {address: 127.0.0.1}",
            "robot1: {address: 127.0.0.1, payload_environment: {API_TOKEN_FILE: /run/secrets/api, "
            "TLS_KEY: /run/secrets/tls}, payload_secret_files: {api: ~/.config/robotfleet/api-token, "
            "tls: /etc/robotfleet/tls.key}}",
        )
    )
    git(site["checkout"], "commit", "-qam", "secrets in files")
    assert "publish: release 1 (" in publish(site).stdout


def test_export_refuses_a_release_whose_fleet_file_holds_a_secret(site, monkeypatch):
    """A release an earlier robotfleet published with a token in its fleet
    file: export re-signs nothing and writes nothing to the medium."""
    from robotfleet import deploy_roles
    from robotfleet.pull.operator import publishing
    from robotfleet.pull.operator.keys import KeyDir
    from robotfleet.pull.operator.repository import Repository

    with_secrets(site)
    repository = Repository(site["base"] / "published")
    options, now = publishing.Options(), pullkit.NOW
    with monkeypatch.context() as earlier:  # publish as it was before the refusal
        earlier.setattr(publishing, "secret_refusal", lambda fleet, path: None)
        work = site["base"] / "work"
        work.mkdir()
        record, files = publishing.build(
            site["checkout"], options, deploy_roles.roles(), deploy_roles.registry(), 1, now, work
        )
        publishing.publish(repository, record, files, KeyDir(site["keys"]), options, now)
    signed = pullkit.tree_state(repository.path)
    medium = site["base"] / "usb"
    done = robotfleet_cmd(
        "export",
        medium,
        "--to-dir",
        repository.path,
        "--checkout",
        site["checkout"],
        "--keys",
        site["keys"],
        check=False,
    )
    assert done.returncode == 2
    assert done.stderr == "export: " + REFUSED_TOKEN.format(more="1 more in the file", done="exported") + "\n"
    assert list(medium.iterdir()) == [] and pullkit.tree_state(repository.path) == signed
