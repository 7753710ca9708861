"""What counts as a secret (issue 50, item 4): one rule in robotfleet/secrets.py
decides what inventory, --diff and the deploy's log mask and what a release
refuses to carry.  A key names a secret by its last word; a path says where
a secret is, not what it is."""

from __future__ import annotations

import pytest

from robotfleet import secrets

SECRET = [
    "API_TOKEN",
    "AWS_SECRET_ACCESS_KEY",
    "AWS_SESSION_TOKEN",
    "GITHUB_TOKEN",
    "client_secret",
    "clientSecret",
    "apiKey",
    "APIKey",
    "X-API-Key",
    "DB_PASSWORD",
    "dbpassword",
    "MQTT_PASS",
    "smtp_passwd",
    "gpg_passphrase",
    "private_key",
    "CREDENTIALS",
    "ssh_password",
    "ssh_key_password",
    "ansible_become_pass",
    "payload_lock_token",
]
NOT_SECRET = [
    "docker_apt_key_fingerprint",  # a fingerprint: public
    "docker_apt_key_path",
    "docker_apt_key_url",
    "AWS_ACCESS_KEY_ID",  # the key's id, not the key
    "token_realms",
    "TOKEN_REFRESH_INTERVAL",
    "payload_registry_password_env",  # the name of the variable that holds it
    "password_file",
    "POSTGRES_PASSWORD_FILE",
    "JWT_PUBLIC_KEY",
    "pull_remote_host_keys",
    "ROS_SECURITY_KEYSTORE",
    "udev_passthrough",
    "bypass",
    "ssh_key",  # pyinfra's: a file name, whatever its form
    "ssh_revoked_host_keys",
    "payload_secret_files",
]


@pytest.mark.parametrize("key", SECRET)
def test_a_key_whose_last_word_names_a_secret_holds_one(key):
    assert secrets.named_secret(key)
    assert secrets.held_in({"payload_environment": {key: "v4lue-7"}}) == {"v4lue-7"}


@pytest.mark.parametrize("key", NOT_SECRET)
def test_a_key_that_names_something_about_a_secret_holds_none(key):
    assert not secrets.named_secret(key)
    assert secrets.held_in({key: "v4lue-7"}) == set()


@pytest.mark.parametrize("path", ["/run/secrets/db", "~/.ssh/id_ed25519", "/etc/ssl/private/robot.key", "/certs/k.pem"])
def test_a_path_says_where_a_secret_is_and_is_shown(path):
    """GOOGLE_APPLICATION_CREDENTIALS, TLS_KEY: a path to the file that
    holds the secret, which may travel; the file's content does not."""
    data = {"GOOGLE_APPLICATION_CREDENTIALS": path, "TLS_KEY": path, "ssh_key": "keys/robot1"}
    assert secrets.held_in(data) == set()


@pytest.mark.parametrize("value", ["/K7MDENG/bPxRfiCYEXAMPLEKEY", "/etc", "keys/robot1", "wJalr/XUtn+FEMI", "/a b/c"])
def test_a_value_that_only_looks_a_little_like_a_path_is_still_a_secret(value):
    """A base64 secret may start with "/": only a plain first directory makes a path."""
    assert secrets.held_in({"AWS_SECRET_ACCESS_KEY": value}) == {value}


def test_each_secret_is_found_with_the_field_that_holds_it():
    data = {
        "docker_daemon_options": {"proxies": {"http-proxy": "http://u:pr0xy@proxy.lan:3128"}},
        "payload_environment": {"ROS_DOMAIN_ID": "7", "API_TOKEN": "t0ken", "CERT": "/run/secrets/c"},
        "payload_services": {"slam": {"secrets": ["db_password"], "environment": {"apiKey": "k3y"}}},
        "payload_secret_files": {"db_password": "/home/op/db.pw"},
    }
    assert secrets.found_in(data) == [
        ("docker_daemon_options.proxies.http-proxy", "pr0xy"),
        ("payload_environment.API_TOKEN", "t0ken"),
        ("payload_services.slam.environment.apiKey", "k3y"),
    ]


def test_masking_hides_every_secret_the_rule_finds():
    data = {"payload_environment": {"API_TOKEN": "tok-91f", "AWS_SECRET_ACCESS_KEY": "wJalr/XUtn+FEMI"}}
    text = "API_TOKEN=tok-91f AWS_SECRET_ACCESS_KEY=wJalr/XUtn+FEMI"
    assert secrets.mask(text, secrets.held_in(data)) == "API_TOKEN=**** AWS_SECRET_ACCESS_KEY=****"


def test_a_refused_value_is_quoted_in_its_line_without_the_secret_it_holds():
    """A token written unquoted (an integer, refused) is masked in the problem line that quotes it."""
    from tests.unit.harness import fleet_problems

    host = {"payload_image": "reg.example.com/p:1", "payload_environment": {"API_TOKEN": 918273645, "RATE": 10}}
    assert fleet_problems({"robots": {"hosts": {"r1": host}}}) == [
        "robots.yaml: r1.payload_environment.API_TOKEN: expected a string, got ****; quote it",
        "robots.yaml: r1.payload_environment.RATE: expected a string, got 10; quote it",
    ]
    assert secrets.found_in({"PIN_PASSWORD": 4711, "retries": 3, "use_key": True}) == [("PIN_PASSWORD", "4711")]
