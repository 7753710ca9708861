"""The corpus of fleet documents, each with the lines the fleet check must
give for it (tests/unit/test_fleet_corpus.py asserts them; the schema's and
the schema-agreement tests read it too)."""

from __future__ import annotations

from robotfleet import CHECKOUT as ROOT
from tests.unit import harness as fleet

BASE = "all:\n  vars:\n    payload_image: reg.example.com/p:1\n"


def lines(text) -> list[str]:
    try:
        fleet.parse(text, "f.yaml")
    except fleet.FleetError as error:
        return error.lines
    return []


def host(*settings: str) -> str:
    """A fleet with one robot r1 whose settings are the given YAML lines."""
    return BASE + "robots:\n  hosts:\n    r1:\n" + "".join(f"      {line}\n" for line in settings)


def bomb(under: str) -> str:
    """Billion laughs: 9 levels of 9 aliases (387 million leaves) under a setting."""
    levels = ["x-l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    levels += [f"x-l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 10)]
    return "\n".join(levels) + "\n" + host(f"{under}: {{a: *l9}}")


CORPUS = [
    # 1. wrong types where a scalar or string is assumed; keys must be strings
    ("mapping as image", host("payload_image: {a: 1}"), ["f.yaml: r1.payload_image: expected a string, got a mapping"]),
    (
        "list as serial and symlink",
        host(
            "udev_sensors:",
            "  - {name: a, subsystem: tty, serial: [1]}",
            "  - {name: b, subsystem: tty, serial: '2', symlink: [x]}",
        ),
        [
            "f.yaml: r1.udev_sensors[0].serial: expected a string, got a list",
            "f.yaml: r1.udev_sensors[1].symlink: expected a string, got a list",
        ],
    ),
    (
        "list as sensor name, twice",
        host(
            "udev_sensors:",
            "  - {name: [a], subsystem: tty, serial: '1'}",
            "  - {name: [a], subsystem: tty, serial: '1'}",
        ),
        [
            "f.yaml: r1.udev_sensors[0].name: expected a string, got a list",
            "f.yaml: r1.udev_sensors[1].name: expected a string, got a list",
        ],
    ),
    (
        "refused sensor, duplicates among the others",
        host(
            "udev_sensors:",
            "  - {name: x, subsystem: tty, serial: [1]}",
            "  - {name: a, subsystem: tty, serial: '1'}",
            "  - {name: a, subsystem: tty, serial: '2'}",
        ),
        [
            "f.yaml: r1.udev_sensors[0].serial: expected a string, got a list",
            "f.yaml: r1.udev_sensors[2].name: duplicate sensor name 'a' (also udev_sensors[1])",
            "f.yaml: r1.udev_sensors[2].symlink: /dev/robot/a is already used by udev_sensors[1]",
        ],
    ),
    (
        "number as setting key",
        host("8080: 80"),
        ["f.yaml: r1.8080: a setting name must be a string, got 8080; quote it"],
    ),
    (
        "number as sensor field",
        host("udev_sensors:", "  - {name: a, subsystem: tty, serial: '1', 1: x}"),
        ["f.yaml: r1.udev_sensors[0].1: a sensor field name must be a string, got 1; quote it"],
    ),
    (
        "list as mapping key",
        host("? [a, b]", ": 1"),
        ["f.yaml: line 7: YAML error: a key must be a plain name, not a list"],
    ),
    (
        "not UTF-8",
        (BASE + "robots:\n  hosts:\n    r1: {address: caf\xe9}\n").encode("latin-1"),
        ["f.yaml: line 6: YAML error: not UTF-8 text (byte 0xe9); save the file as UTF-8"],
    ),
    (
        "control character",
        BASE + "robots:\n  hosts:\n    r1: {address: a\x07b}\n",
        ["f.yaml: line 6: YAML error: character U+0007 is not allowed in YAML"],
    ),
    (
        "control character after multibyte text",
        BASE + "robots:\n  hosts:\n    r1: {address: " + "\u00e9" * 40 + "}\n    r2: {address: a\x07b}\n",
        ["f.yaml: line 7: YAML error: character U+0007 is not allowed in YAML"],
    ),
    (
        "deep nesting",
        host("docker_daemon_options: {a: " + "[" * 5000 + "]" * 5000 + "}"),
        ["f.yaml: line 7: YAML error: nested more than 50 levels deep"],
    ),
    (
        "recursive alias",
        host("docker_daemon_options: &a {a: *a}"),
        ["f.yaml: line 7: YAML error: an alias refers to its own anchor (a recursive value)"],
    ),
    (
        "section of the wrong type",
        BASE + "robots: [r1, r2]\n",
        ["f.yaml: robots: expected a group (a mapping with vars, hosts, children), got a list"],
    ),
    (
        "tab indentation",
        BASE + "robots:\n\thosts: {}\n",
        ["f.yaml: line 5: YAML error: found '\\t', which cannot start any token; indent with spaces, not tabs"],
    ),
    (
        "two documents",
        BASE + "---\nrobots: {}\n",
        ["f.yaml: line 4: YAML error: a second YAML document starts here; a fleet file is one document"],
    ),
    (
        "python tag",
        host("payload_image: !!python/object/apply:os.system [id]"),
        ["f.yaml: line 7: YAML error: the YAML tag '!!python/object/apply:os.system' is not supported here"],
    ),
    (
        "set tag",
        host("docker_users: !!set {a, b}"),
        ["f.yaml: line 7: YAML error: the YAML tag '!!set' is not supported here"],
    ),
    (
        "unknown tag",
        host("payload_image: !env IMAGE"),
        ["f.yaml: line 7: YAML error: the YAML tag '!env' is not supported here"],
    ),
    # 2. alias bomb under a free-form setting: bounded, one line
    (
        "billion laughs",
        bomb("docker_daemon_options"),
        ["f.yaml: r1.docker_daemon_options: more than 10000 values (YAML aliases expand); daemon options are small"],
    ),
    (
        "billion laughs under many options",
        bomb("docker_daemon_options").replace(
            "{a: *l9}", "{" + ", ".join(f"features{i}: *l9" for i in range(3)) + ", runtimes: {a: *l9, b: *l9}}"
        ),
        ["f.yaml: r1.docker_daemon_options: more than 10000 values (YAML aliases expand); daemon options are small"],
    ),
    ("too large", "# " + "x" * (32 * 2**20) + "\n", ["f.yaml: larger than 32 MiB; a fleet file is text people edit"]),
    (
        "billion laughs in a known option",
        bomb("docker_daemon_options").replace("{a: *l9}", "{features: {a: *l9}}"),
        ["f.yaml: r1.docker_daemon_options: more than 10000 values (YAML aliases expand); daemon options are small"],
    ),
    # 3. no hosts is an error, not a silent no-op
    (
        "empty file",
        "",
        [
            "f.yaml: no hosts: declare them under robots.hosts or laptops.hosts "
            "([robots] or [laptops] in an INI inventory)"
        ],
    ),
    (
        "only comments",
        "# the fleet\n",
        [
            "f.yaml: no hosts: declare them under robots.hosts or laptops.hosts "
            "([robots] or [laptops] in an INI inventory)"
        ],
    ),
    (
        "hosts left empty",
        BASE + "robots:\n  hosts:\n",
        [
            "f.yaml: no hosts: declare them under robots.hosts or laptops.hosts "
            "([robots] or [laptops] in an INI inventory)"
        ],
    ),
    # 4. addresses
    ("bad IPv4", host("address: 127.0.0.300"), ["f.yaml: r1.address: '127.0.0.300' is not a valid IPv4 address"]),
    (
        "host:port",
        host("address: '10.0.0.5:2222'"),
        [
            "f.yaml: r1.address: expected a host name or an IP address, got '10.0.0.5:2222'; "
            "put the port in ssh_port: 2222"
        ],
    ),
    (
        "[IPv6]:port",
        host("address: '[fd00::5]:2222'"),
        [
            "f.yaml: r1.address: expected a host name or an IP address, got '[fd00::5]:2222'; "
            "put the port in ssh_port: 2222"
        ],
    ),
    (
        "space in address",
        host("address: robot 1"),
        ["f.yaml: r1.address: expected a host name or an IP address, got 'robot 1'"],
    ),
    (
        "good addresses",
        BASE + "robots:\n  hosts:\n    r1: {address: 'fe80::1'}\n    r2: {address: robot2.lan}\n"
        "    r3: {address: 10.0.0.3}\n    r4: {}\n",
        [],
    ),
    # 5. YAML surprises in names (the fleet file is YAML 1.2: yes/no/on/off are text)
    (
        "octal-looking host name",
        BASE + "robots:\n  hosts:\n    010: {}\n",
        ["f.yaml: 010: a host name must be a string, got 010 (read by YAML as 10); quote it"],
    ),
    (
        "boolean-looking host name",
        BASE + "robots:\n  hosts:\n    true: {}\n    r2: {}\n",
        ["f.yaml: true: a host name must be a string, got true (read by YAML as a boolean (true)); quote it"],
    ),
    ("yes and on are host names", BASE + "robots:\n  hosts:\n    yes: {}\n    on: {}\n", []),
    ("quoted host name", BASE + "robots:\n  hosts:\n    '010': {}\n", []),
    # 6. docker daemon options checked before connecting
    (
        "daemon option typo",
        host("docker_daemon_options: {live-restor: true}"),
        ["f.yaml: r1.docker_daemon_options.live-restor: unknown daemon.json option (did you mean 'live-restore'?)"],
    ),
    (
        "daemon option types",
        host("docker_daemon_options: {debug: 'yes', dns: [1], log-opts: {max-size: 10}}"),
        [
            "f.yaml: r1.docker_daemon_options.debug: expected true or false, got 'yes'",
            "f.yaml: r1.docker_daemon_options.dns[0]: expected a string, got 1; quote it",
            "f.yaml: r1.docker_daemon_options.log-opts.max-size: expected a string, got 10; quote it",
        ],
    ),
    # 7. positions: where a quote or flow collection was opened; one line per problem
    (
        "unclosed quote",
        BASE + 'robots:\n  hosts:\n    r1: {address: "10.0.0.1}\n    r2: {}\n',
        [
            "f.yaml: line 6: YAML error: a quoted scalar opened here (column 19) is not closed: "
            "found unexpected end of stream (line 8, column 1)"
        ],
    ),
    (
        "quote closed by the next value's quote",
        BASE + 'robots:\n  hosts:\n    r1:\n      payload_image: "reg.example.com/p:1\n'
        '      ssh_port: 22\n    r2:\n      ssh_port: 23\n    r3:\n      payload_image: "reg.example.com/p:2"\n',
        [
            "f.yaml: line 7: YAML error: a quoted value opened here (column 22) runs on to line 12, where "
            "did not find expected key (column 23); is its closing quote missing?"
        ],
    ),
    (
        "a value quoted over several lines",
        host('payload_image: "reg.example.com/', '  p:1"', "ssh_port: 22"),
        ["f.yaml: r1.payload_image: 'reg.example.com/ p:1' is not a valid image reference"],
    ),
    (
        "unclosed flow mapping",
        BASE + "robots:\n  hosts:\n    r1: {address: 10.0.0.1\n    r2: {}\n",
        [
            "f.yaml: line 6: YAML error: a flow mapping opened here (column 9) is not closed: "
            "did not find expected ',' or '}' (line 7, column 7)"
        ],
    ),
    (
        "bad indentation",
        BASE + "robots:\n  hosts:\n    r1: {}\n   r2: {}\n",
        ["f.yaml: line 7: YAML error: did not find expected key (while parsing a block mapping from line 5)"],
    ),
    (
        "newline in host name",
        BASE + 'robots:\n  hosts:\n    "r1\\nr2": {}\n',
        ["f.yaml: 'r1\\nr2': invalid host name (letters, digits, . _ -)"],
    ),
    (
        "newline in a key",
        host('"ssh_\\nport": 22'),
        ["f.yaml: r1.'ssh_\\nport': unknown setting (did you mean 'ssh_port'?)"],
    ),
    (
        "duplicate host",
        BASE + "robots:\n  hosts:\n    r1: {}\n    r1: {}\n",
        ["f.yaml: line 7: YAML error: duplicate key 'r1'"],
    ),
    # 8. merge keys are valid YAML
    (
        "merge keys",
        "x-camera: &camera {subsystem: video4linux, vendor_id: '046d', product_id: '0825'}\n"
        + host(
            "udev_sensors:",
            "  - {<<: *camera, name: front, usb_port: '1-1.2'}",
            "  - {<<: *camera, name: back, usb_port: '1-1.3'}",
        ),
        [],
    ),
    (
        "merge keys, then a mistake",
        "x-camera: &camera {subsystem: video4linux, vendor_id: '046d', product_id: '0825'}\n"
        + host("udev_sensors:", "  - {<<: *camera, name: front}", "  - {<<: *camera, name: back}"),
        [
            "f.yaml: r1.udev_sensors[1]: back matches the same devices as front (udev_sensors[0]); "
            "add a serial or usb_port to tell them apart"
        ],
    ),
    (
        "merge of a scalar",
        host("udev_sensors:", "  - {<<: 1, name: a}"),
        ["f.yaml: line 8: YAML error: a merge key (<<) takes a mapping or a list of mappings"],
    ),
    # 9. yes/no are text in YAML 1.2: the documented words as written
    ("strict host key checking no", host("ssh_strict_host_key_checking: no", "payload_restart_policy: no"), []),
    (
        "restart policy yes",
        host("payload_restart_policy: yes"),
        ["f.yaml: r1.payload_restart_policy: expected one of no, always, on-failure, unless-stopped, got 'yes'"],
    ),
    (
        "restart policy true",
        host("payload_restart_policy: true"),
        ["f.yaml: r1.payload_restart_policy: expected a string, got a boolean (true); quote it"],
    ),
    # issue 8, item 2: URLs are http(s) URLs without shell characters
    (
        "key URL injection",
        host("docker_apt_key_url: 'https://mirror.lan/gpg?x=$(touch${IFS}/tmp/x)'"),
        [
            "f.yaml: r1.docker_apt_key_url: expected an http(s) URL without spaces or shell characters ($ ` ; | & "
            "quotes), got 'https://mirror.lan/gpg?x=$(touch${IFS}/tmp/x)'"
        ],
    ),
    (
        "repo URL scheme",
        host("docker_repo_url: 'ftp://mirror.lan/linux'"),
        [
            "f.yaml: r1.docker_repo_url: expected an http(s) URL without spaces or shell characters ($ ` ; | & "
            "quotes), got 'ftp://mirror.lan/linux'"
        ],
    ),
    # a refused value is shown, but never the password a URL in it carries
    (
        "mirror URL with a password",
        host("docker_registry_mirrors: ['https://ci:hunter2@mirror.lan/$(x)']"),
        [
            "f.yaml: r1.docker_registry_mirrors[0]: expected an http(s) URL without spaces or shell characters ($ ` "
            "; | & quotes), got 'https://ci:****@mirror.lan/$(x)'"
        ],
    ),
    (
        "good URLs",
        host(
            "docker_repo_url: 'http://10.0.0.2:8080/linux'",
            "docker_apt_key_url: 'https://mirror.lan/keys/docker.asc?v=2'",
            "docker_registry_mirrors: ['https://[fd00::1]:5000']",
        ),
        [],
    ),
    # issue 8, item 4: environment values are strings, quoted in YAML
    (
        "environment YAML traps",
        host("payload_environment: {A: NO, B: 1.10, C: 0755, D: 12:30, E: 'NO', F: true}"),
        [
            f"f.yaml: r1.payload_environment.{key}: expected a string, got {got}; quote it"
            for key, got in (("B", "1.10 (read by YAML as 1.1)"), ("C", "0755 (read by YAML as 755)"))
        ]
        + [
            "f.yaml: r1.payload_environment.F: expected a string, got a boolean (true); quote it "
            "(YAML reads an unquoted true/false as a boolean)"
        ],
    ),
    (
        "respelled numbers in number settings",
        host("ssh_port: 0022", "payload_health_timeout: 1:30"),
        [
            "f.yaml: r1.ssh_port: expected a whole number, got 0022 (read by YAML as 22)",
            "f.yaml: r1.payload_health_timeout: expected a whole number, got '1:30'",
        ],
    ),
    # issue 8, item 7: paths root creates are not in world-writable directories
    (
        "payload_dir /tmp",
        host("payload_dir: /tmp"),
        [
            "f.yaml: r1.payload_dir: '/tmp' is in the world-writable /tmp; "
            "use a directory only root can write (e.g. under /var/lib)"
        ],
    ),
    (
        "cookie dir under /dev/shm",
        host("x11_cookie_dir: /dev/shm/x"),
        [
            "f.yaml: r1.x11_cookie_dir: '/dev/shm/x' is in the world-writable /dev/shm; "
            "use a directory only root can write (e.g. under /var/lib)"
        ],
    ),
    (
        "dotted way into /var/tmp",
        host("payload_dir: /var/./tmp//robot"),
        [
            "f.yaml: r1.payload_dir: '/var/./tmp//robot' is in the world-writable /var/tmp; "
            "use a directory only root can write (e.g. under /var/lib)"
        ],
    ),
    (
        "dot-dot",
        host("payload_dir: /var/lib/../../tmp"),
        ["f.yaml: r1.payload_dir: paths must not contain '..', got '/var/lib/../../tmp'"],
    ),
    # issue 27, item 1: credentials per registry, from where they are kept, never the values
    (
        "registry auths from the environment and files",
        host(
            "payload_registry_auths: {reg2.example.com:5000: {username_env: REG2_USER, password_file: "
            "~/.config/robotfleet/reg2},",
            "  docker.io: {username_file: /etc/robotfleet/hub-user, password_env: HUB_TOKEN,",
            "              token_realms: ['https://auth.docker.io/token']}}",
        ),
        [],
    ),
    (
        "a password in the fleet file",
        host("payload_registry_auths: {reg.example.com: {username: robot, password: s3cret}}"),
        [
            "f.yaml: r1.payload_registry_auths.reg.example.com.username: unknown field (did you mean 'username_env'?)",
            "f.yaml: r1.payload_registry_auths.reg.example.com.password: unknown field (did you mean 'password_env'?)",
            "f.yaml: r1.payload_registry_auths.reg.example.com: give one of username_env (an environment variable) or "
            "username_file (a file outside the checkout), not the value itself",
            "f.yaml: r1.payload_registry_auths.reg.example.com: give one of password_env (an environment variable) or "
            "password_file (a file outside the checkout), not the value itself",
        ],
    ),
    (
        "a relative credential file and a plain-HTTP realm",
        host(
            "payload_registry_auths: {reg.example.com: {username_env: U, password_file: secrets/reg, token_realms: ['http://auth.lan/t']}}"
        ),
        [
            "f.yaml: r1.payload_registry_auths.reg.example.com.password_file: expected an absolute path (or ~/...) "
            "on this machine, got 'secrets/reg'",
            "f.yaml: r1.payload_registry_auths.reg.example.com.token_realms[0]: expected an https URL, got 'http://auth.lan/t'",
        ],
    ),
    (
        "a credential file inside the checkout",
        host(
            "payload_registry_auths: {reg.example.com: {username_env: U, password_file: "
            f"{ROOT}/inventories/reg.pw}}}}"
        ),
        [
            f"f.yaml: r1.payload_registry_auths.reg.example.com.password_file: '{ROOT}/inventories/reg.pw' is inside "
            f"the checkout {ROOT}; keep credentials outside the repository (e.g. ~/.config/robotfleet/)"
        ],
    ),
    (
        "a registry that is a URL",
        host("payload_registry_auths: {'https://reg.example.com': {username_env: U, password_env: P}}"),
        [
            "f.yaml: r1.payload_registry_auths.https://reg.example.com: expected a registry host[:port], got 'https://reg.example.com'"
        ],
    ),
    # issue 27, item 10: paths root creates, writes or trusts are in a place only root writes
    *[
        (
            f"payload_dir under {place}",
            host(f"payload_dir: {place}/robot"),
            [
                f"f.yaml: r1.payload_dir: '{place}/robot' is in {shown}, {why}; "
                "use a directory only root can write (e.g. under /var/lib)"
            ],
        )
        for place, shown, why in (
            ("/var/crash", "/var/crash", "world-writable on Ubuntu (crash reports)"),
            ("/var/spool", "/var/spool", "holds directories others write (mail, cron, print queues)"),
            ("/var/spool/mail", "/var/spool", "holds directories others write (mail, cron, print queues)"),
            ("/var/mail", "/var/mail", "writable by group mail"),
            ("/var/local", "/var/local", "writable by group staff"),
            ("/var/metrics", "/var/metrics", "world-writable on Ubuntu"),
            ("/home/ops", "/home", "users own their home directories"),
            ("/media/ops", "/media", "users' removable media (mounted for them)"),
            ("/usr/local", "/usr/local", "writable by group staff on older Debian"),
            ("/var/lib/php/sessions", "/var/lib/php/sessions", "world-writable (1733)"),
        )
    ],
    *[
        (
            f"payload_dir {place}",
            host(f"payload_dir: {place}"),
            [
                f"f.yaml: r1.payload_dir: '{place}' is not in a place only root writes on Debian and Ubuntu (/etc, "
                "/opt, /srv, /mnt, /root, /usr, /var/lib, /var/opt, /var/cache, /var/log, /run, /proc/driver); use a "
                "directory there (e.g. under /var/lib)"
            ],
        )
        for place in ("/data/robot", "/var/robot", "/", "/boot/p", "/proc/1/root/var/lib/p", "/dev/robot")
    ],
    (
        "lock file in /var/lock",
        host("payload_update_lock_path: /var/lock/robot"),
        [
            "f.yaml: r1.payload_update_lock_path: '/var/lock/robot' is in the world-writable /run/lock; "
            "use a directory only root can write (e.g. under /var/lib)"
        ],
    ),
    *[
        (
            f"private path under {place}",
            host(
                f"payload_dir: {place}/robot-payload",
                f"payload_update_lock_path: {place}/robot.lock",
                f"x11_cookie_dir: {place}/x11",
            ),
            [],
        )
        for place in (
            "/etc",
            "/opt",
            "/srv",
            "/mnt/ssd",
            "/root",
            "/usr/share",
            "/var/lib",
            "/var/opt",
            "/var/cache",
            "/var/log",
            "/run",
            "/var/run",
            "/var//lib/.",
        )
    ],
    ("driver file under /proc/driver", host("gpu_driver_version_file: /proc/driver/nvidia/version"), []),
    # issue 27, item 12: the Docker API on TCP only with TLS client verification, or opted in by name
    *[
        (
            f"unauthenticated TCP API {listener}",
            host(f"docker_daemon_options: {{hosts: ['unix:///run/docker.sock', '{listener}']}}"),
            [
                f"f.yaml: r1.docker_daemon_options.hosts[1]: '{listener}' opens the Docker API on TCP without TLS "
                "client verification (missing: tlsverify, tlscacert, tlscert, tlskey): anyone who reaches it is root "
                "on this host; set tlsverify: true, tlscacert, tlscert and tlskey, or "
                "docker_allow_unauthenticated_tcp: true"
            ],
        )
        for listener in ("tcp://0.0.0.0:2375", "0.0.0.0:2375", "tcp://", "tcp://127.0.0.1:2375")
    ],
    (
        "TCP API with tls but no client verification",
        host(
            "docker_daemon_options: {hosts: ['tcp://0.0.0.0:2376'], tls: true, tlsverify: false, tlscert: "
            "/etc/docker/c.pem, "
            "tlskey: /etc/docker/k.pem, tlscacert: /etc/docker/ca.pem}"
        ),
        [
            "f.yaml: r1.docker_daemon_options.hosts[0]: 'tcp://0.0.0.0:2376' opens the Docker API on TCP without TLS "
            "client verification (missing: tlsverify): anyone who reaches it is root on this host; "
            "set tlsverify: true, tlscacert, tlscert and tlskey, or docker_allow_unauthenticated_tcp: true"
        ],
    ),
    (
        "TCP API with client verification",
        host(
            "docker_daemon_options: {hosts: ['fd://', 'tcp://0.0.0.0:2376'], tlsverify: true, tlscert: "
            "/etc/docker/c.pem, tlskey: /etc/docker/k.pem, tlscacert: /etc/docker/ca.pem}"
        ),
        [],
    ),
    (
        "unauthenticated TCP API opted in by name",
        host("docker_daemon_options: {hosts: ['tcp://0.0.0.0:2375']}", "docker_allow_unauthenticated_tcp: true"),
        [],
    ),
    ("unix sockets only", host("docker_daemon_options: {hosts: ['unix:///run/docker.sock', 'fd://']}"), []),
    # issue 8, item 10: image tags are ASCII
    (
        "Unicode digit in tag",
        host("payload_image: 'reg.example.com/p:v\uff11'"),
        ["f.yaml: r1.payload_image: 'reg.example.com/p:v\uff11' is not a valid image reference"],
    ),
]
