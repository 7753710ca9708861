"""`--diff` shows what each managed file would become; `--dry` names the
reason a host will fail while planning and counts it as failed.  pyinfra's
own CLI does the same in tests/integration/test_dry_and_diff.py."""

import logging

import pytest

from robotfleet.host import operations
from robotfleet.host.fixtures import file_state as _file
from robotfleet.host.snapshot import FileState
from tests.fixtures import ROOT
from tests.unit.harness import ROBOT, converged, find, fresh_host, plan
from tests.unit.samples import DAEMON_JSON, DRIFTED, drifted_robot


@pytest.fixture
def log(caplog):
    caplog.set_level(logging.INFO, logger="pyinfra")
    return caplog


def test_unified_diff_of_a_file():
    assert operations.unified_diff("/f", "a\nb\n", "a\nc\n") == [
        "--- /f (on the host)",
        "+++ /f (planned)",
        "@@ -1,2 +1,2 @@",
        " a",
        "-b",
        "+c",
    ]


def test_diff_shows_the_drifted_file_and_reads_only_that_file(log):
    result = plan(
        {"r1": ("robots", ROBOT, drifted_robot())}, run=False, diff=True, contents={"r1": {DAEMON_JSON: DRIFTED}}
    )
    # Planning sent one read: the content of the one file the snapshot found different.
    assert result["r1"] == [f"( test -e {DAEMON_JSON} && cat {DAEMON_JSON} ) || echo __pyinfra_missing_{DAEMON_JSON}"]
    lines = [r.getMessage().strip() for r in log.records]
    assert f"[@fake/r1] Will modify {DAEMON_JSON}" in "\n".join(lines)
    start = lines.index(f"--- {DAEMON_JSON} (on the host)")
    assert lines[start : start + 5] == [
        f"--- {DAEMON_JSON} (on the host)",
        f"+++ {DAEMON_JSON} (planned)",
        "@@ -1,3 +1,8 @@",
        "{",
        '-  "live-restore": false',
    ]
    assert '+  "live-restore": true,' in lines and result.failed == set()


def test_diff_of_a_new_file_reads_nothing(log):
    result = plan({"r1": ("robots", ROBOT, fresh_host("debian-13"))}, run=False, diff=True)
    assert not find(result["r1"], "cat ")
    text = "\n".join(r.getMessage() for r in log.records)
    assert f"Will create {DAEMON_JSON}" in text and '+  "live-restore": true,' in text


def test_converged_host_with_diff_sends_nothing_and_prints_no_diff(log):
    result = plan({"r1": ("robots", ROBOT, converged("robots", ROBOT, "debian-13"))}, diff=True)
    assert result["r1"] == []
    assert not [r for r in log.records if "Will modify" in r.getMessage()]


def test_without_diff_no_content_is_fetched(log):
    result = plan({"r1": ("robots", ROBOT, drifted_robot())}, run=False)
    assert result["r1"] == [] and "Will modify" not in log.text


def test_diff_is_printed_once_per_file_in_a_full_run(log):
    plan({"r1": ("robots", ROBOT, drifted_robot())}, diff=True, contents={"r1": {DAEMON_JSON: DRIFTED}})
    assert len([r for r in log.records if f"Will modify {DAEMON_JSON}" in r.getMessage()]) == 1


@pytest.mark.parametrize(
    "name, data, snap, reason",
    [
        ("arch", ROBOT, fresh_host("ubuntu-24.04", "armhf"), "docker: architecture armhf is not supported"),
        (
            "user",
            {**ROBOT, "docker_users": ["ops", "ghost"]},
            fresh_host("debian-13"),
            "docker_users: ghost does not exist on this host",
        ),
        (
            "settings",
            {**ROBOT, "ssh_port": "x"},
            fresh_host("debian-13"),
            "settings: ssh_port: expected a whole number",
        ),
        (
            "x11",
            {**ROBOT, "x11_enabled": True, "x11_user": "alice"},
            fresh_host("debian-13"),
            "x11_user: alice does not exist on this host",
        ),
        ("dir", ROBOT, "daemon.json is a directory", "/etc/docker/daemon.json exists but is not a regular file"),
    ],
)
def test_dry_run_names_the_failure_while_planning_and_counts_it(log, name, data, snap, reason):
    if snap == "daemon.json is a directory":
        snap = converged("robots", ROBOT, "debian-13")
        snap.files[DAEMON_JSON] = FileState("dir", None, "755", "root", "root")
    result = plan({"bad": ("robots", data, snap), "good": ("robots", ROBOT, fresh_host("debian-13"))}, run=False)
    assert result.failed == {"bad"}
    errors = [r.getMessage() for r in log.records if r.levelno >= logging.ERROR]
    assert len([e for e in errors if e.startswith("[@fake/bad] ") and reason in e]) == 1, errors
    assert result["bad"] == [] and result["good"] == []  # planning sends nothing else


def test_a_planned_failure_still_fails_the_host_when_run():
    result = plan(
        {
            "bad": ("robots", ROBOT, fresh_host("ubuntu-24.04", "armhf")),
            "good": ("robots", ROBOT, fresh_host("debian-13")),
        }
    )
    assert result.failed == {"bad"} and "architecture armhf is not supported" in result["bad"][0]
    assert find(result["good"], "payloadctl apply")


def test_diff_masks_the_passwords_in_daemon_json_on_both_sides(log):
    """daemon.json's proxies carry credentials: --diff shows where they go,
    never what they are (issue 17, item 7)."""
    old = '{\n  "proxies": {"http-proxy": "http://robot:oldS3cret@proxy.lan:3128"}\n}\n'
    snap = converged("robots", ROBOT, "debian-13")
    snap.files[DAEMON_JSON] = _file(old)
    data = {
        **ROBOT,
        "docker_daemon_options": {
            "proxies": {"http-proxy": "http://robot:n3wS3cret@proxy.lan:3128", "no-proxy": "localhost"}
        },
    }
    plan({"r1": ("robots", data, snap)}, run=False, diff=True, contents={"r1": {DAEMON_JSON: old}})
    text = "\n".join(r.getMessage() for r in log.records)
    assert "http://robot:****@proxy.lan:3128" in text and "Will modify" in text
    assert "S3cret" not in text


def test_masking_leaves_urls_without_a_password_alone():
    assert operations.mask_credentials('"https://mirror.lan/x" "http://u:p@h:1/" "ssh://git@host"') == (
        '"https://mirror.lan/x" "http://u:****@h:1/" "ssh://git@host"'
    )


# Passwords of every shape (issue 27, item 6): a quote, raw @ (URL parsers
# take the last @), a double quote and a backslash (JSON-escaped in
# daemon.json), non-ASCII (\u-escaped), a raw slash, percent-encoding, a space.
HOSTILE_PASSWORDS = ["it's", "p@ss@word", 'say"hi', "back\\slash", "pässwörd", "sl/ash", "per%40cent", "sp ace"]


@pytest.mark.parametrize("password", HOSTILE_PASSWORDS)
def test_diff_masks_every_password_the_fleet_holds_by_value(log, password):
    import json

    from robotfleet import secrets

    old_password = "0ld'p@ss"  # only on the host: masked by the URL's shape
    old = json.dumps({"proxies": {"http-proxy": f"http://robot:{old_password}@proxy.lan:3128"}}, indent=2) + "\n"
    snap = converged("robots", ROBOT, "debian-13")
    snap.files[DAEMON_JSON] = _file(old)
    data = {
        **ROBOT,
        "docker_daemon_options": {
            "proxies": {
                "http-proxy": f"http://robot:{password}@proxy.lan:3128",
                "https-proxy": f"http://robot:{password}@proxy.lan:3129",
            }
        },
    }
    plan({"r1": ("robots", data, snap)}, run=False, diff=True, contents={"r1": {DAEMON_JSON: old}})
    # the checkout's path (deploy.py's, in the last line) is no secret: a checkout in /work/wt/sshidle holds "ss"
    text = "\n".join(r.getMessage() for r in log.records).replace(str(ROOT), "<checkout>")
    assert "Will modify" in text and "proxy.lan:3129" in text
    for secret in (password, old_password):
        for form in secrets.forms(secret) | {secret.split("@")[-1], secret.split("/")[-1]}:
            assert form not in text, (form, text)
    changed = [line for line in text.splitlines() if "http-proxy" in line and line.strip()[:1] in "+-"]
    assert len(changed) == 2 and all("http://robot:****@proxy.lan:3128" in line for line in changed), changed


def test_the_secrets_of_a_host_are_every_url_password_and_password_value_in_its_data():
    from robotfleet import secrets

    data = {
        "ssh_password": "s5h-pw",
        "docker_daemon_options": {
            "proxies": {"http-proxy": "http://u:a@b@p:1"},
            "registry-mirrors": ["https://m.lan", "https://x:y'z@m2"],
        },
        "payload_environment": {"DB": "postgres://app:db%2Fpw@db/app"},
        "ssh_port": 22,
        "payload_dir": "/var/lib/p",
    }
    assert secrets.held_in(data) >= {"s5h-pw", "a@b", "y'z", "db%2Fpw"}
    assert secrets.mask("db/pw and db%2Fpw and a@b", secrets.held_in(data)) == "**** and **** and ****"


def test_masking_by_shape_reads_the_password_as_url_parsers_do():
    from robotfleet import secrets

    assert secrets.mask('"http://u:p@ss@h:1/" "http://u:it\'s@h" "http://u:q\\"x@h"') == (
        '"http://u:****@h:1/" "http://u:****@h" "http://u:****@h"'
    )


def test_diff_masks_the_registry_passwords_too(log, monkeypatch):
    """The secrets a role holds beyond the data (Role.secrets: the registry
    passwords read from the environment) are masked wherever they appear."""
    monkeypatch.setenv("PAYLOAD_REGISTRY_USERNAME", "robot")
    monkeypatch.setenv("PAYLOAD_REGISTRY_PASSWORD", "reg-pw-7x!")
    data = {**ROBOT, "docker_daemon_options": {"labels": ["pull-token=reg-pw-7x!"]}}
    plan({"r1": ("robots", data, drifted_robot())}, run=False, diff=True, contents={"r1": {DAEMON_JSON: DRIFTED}})
    text = "\n".join(r.getMessage() for r in log.records)
    assert '"pull-token=****"' in text and "reg-pw-7x" not in text


def test_diff_masks_every_value_whose_key_names_a_secret(log):
    """API_TOKEN, AWS_SECRET_ACCESS_KEY (issue 50, item 4): held for the host
    like a password, so wherever their values appear they are masked."""
    environment = {"API_TOKEN": "tok-5e1f", "AWS_SECRET_ACCESS_KEY": "wJalr/XUtn+FEMI", "ROS_LOG_DIR": "/tmp/ros"}
    labels = ["api=tok-5e1f", "aws=wJalr/XUtn+FEMI", "logs=/tmp/ros"]
    data = {**ROBOT, "payload_environment": environment, "docker_daemon_options": {"labels": labels}}
    plan({"r1": ("robots", data, drifted_robot())}, run=False, diff=True, contents={"r1": {DAEMON_JSON: DRIFTED}})
    text = "\n".join(r.getMessage() for r in log.records)
    assert '"api=****"' in text and '"aws=****"' in text and '"logs=/tmp/ros"' in text, text
    assert "tok-5e1f" not in text and "XUtn" not in text
