"""Every refusal of a host's compose project, as (field, message) pairs,
including the Compose Specification's published JSON Schema (vendor/: the
compose-spec.json check-jsonschema vendors, copied with its licence; never
hand-written here)."""

from __future__ import annotations

import difflib
import json
import re
from functools import lru_cache
from pathlib import Path

import roles.payload.compose as compose
import roles.payload.payloadctl.imageref as imageref
import roles.payload.payloadctl.platforms as platforms
import roles.payload.secret_files as secret_files
from robotfleet.checkers import key_name
from roles.payload.presets import DDS_DIR, dds_profile_text, dds_vendor
from roles.payload.services import SERVICE_NAME, SHORTHAND_SETTINGS, declared, layer_problems, value_of


@lru_cache(maxsize=1)
def compose_schema() -> dict:
    """The Compose Specification's JSON Schema (vendor/compose-spec.json)."""
    return json.loads(COMPOSE_SCHEMA.read_text())


# check-jsonschema's copy of compose-spec's schema, the same on every operator's
# Python (check-jsonschema itself needs 3.11); refreshed from the release the
# test extra pins (roles/payload/README.md, Checked before connecting).
COMPOSE_SCHEMA = Path(__file__).resolve().parent / "vendor" / "compose-spec.json"


@lru_cache(maxsize=1)
def _validator():
    import jsonschema

    schema = compose_schema()
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema)


def service_keys() -> list[str]:
    """Every key a Compose service may have, for 'did you mean'."""
    schema = compose_schema()
    defs = schema.get("$defs") or schema.get("definitions") or {}
    keys: set[str] = set()
    for name in ("service", "container_spec", "workload_spec"):
        keys |= set((defs.get(name) or {}).get("properties", {}))
    return sorted(keys)


def _field(path) -> str:
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else f".{part}"
    return text


def schema_problems(doc: dict) -> list[tuple[str, str]]:
    """The document against the Compose Specification, as
    (payload_services.<service>.<key...>, message)."""
    # Hosts of a group mostly share one project: validate each distinct one once.
    return list(_schema_problems(json.dumps(doc, sort_keys=True)))


@lru_cache(maxsize=256)
def _schema_problems(canonical: str) -> tuple:
    doc = json.loads(canonical)
    problems = []
    for error in sorted(_validator().iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path]):
        path = list(error.absolute_path)
        if len(path) < 2 or path[0] != "services":
            problems.append(
                (
                    f"payload_services{_field(path[1:] if path[:1] == ['services'] else path)}",
                    f"Compose Specification: {error.message}",
                )
            )
            continue
        where = f"payload_services.{path[1]}{_field(path[2:])}"
        if error.validator in ("unevaluatedProperties", "additionalProperties"):
            unexpected = re.findall(r"'([^']+)'", error.message.split("(", 1)[-1]) or ["?"]
            known = service_keys() if len(path) == 2 else []
            # A key that failed its own subschema is "unevaluated" too: it has its line already.
            unexpected = [k for k in unexpected if k not in known and not k.startswith("x-")]
            for key in unexpected:
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append((f"{where}.{key}", f"not a key of the Compose Specification{hint}"))
            continue
        message = error.message
        if error.validator in ("oneOf", "anyOf") and error.context:
            message = f"{error.instance!r} is not valid here ({error.context[0].message})"
        problems.append((where, f"Compose Specification: {message}"))
    return tuple(problems)


DOCKER_SOCKETS = ("/var/run/docker.sock", "/run/docker.sock", "/var/run/docker", "/run/docker", "/run/containerd")
ROOT_CAPABILITIES = ("ALL", "SYS_ADMIN", "CAP_SYS_ADMIN", "SYS_MODULE", "CAP_SYS_MODULE")


def root_equivalents(spec: dict) -> list[tuple[str, str]]:
    """(subfield, what) for each key that, like privileged, hands a container
    the host: capabilities that are root, the host's pid or user namespace,
    no seccomp/AppArmor, the Docker socket.  A guard against mistakes, not a
    boundary: whoever edits the fleet file is root on every robot anyway."""
    found = []
    for index, cap in enumerate(spec.get("cap_add") or [] if isinstance(spec.get("cap_add"), list) else []):
        if isinstance(cap, str) and cap.upper() in ROOT_CAPABILITIES:
            found.append((f".cap_add[{index}]", f"cap_add {cap}"))
    for key in ("pid", "userns_mode"):
        if spec.get(key) == "host":
            found.append((f".{key}", f"{key}: host"))
    for index, opt in enumerate(spec.get("security_opt") or [] if isinstance(spec.get("security_opt"), list) else []):
        if isinstance(opt, str) and opt.replace("=", ":") in (
            "seccomp:unconfined",
            "apparmor:unconfined",
            "label:disable",
        ):
            found.append((f".security_opt[{index}]", f"security_opt {opt}"))
    for index, source in _bind_sources(spec):
        if any(_under(source.rstrip("/") or "/", socket) for socket in DOCKER_SOCKETS) or source.rstrip("/") == "":
            found.append((f".volumes[{index}]", f"mounting {source}"))
    return found


def _under(path: str, directory: str) -> bool:
    directory = directory.rstrip("/")
    return path == directory or path.startswith(directory + "/")


def _bind_sources(spec: dict) -> list[tuple[int, str]]:
    sources = []
    for index, volume in enumerate(spec.get("volumes") or []):
        if isinstance(volume, str):
            source = volume.split(":", 1)[0] if ":" in volume else None
        elif isinstance(volume, dict) and volume.get("type", "volume") == "bind":
            source = volume.get("source")
        else:
            source = None
        if isinstance(source, str):
            sources.append((index, source))
    return sources


def project_problems(data) -> list[tuple[str, str]]:
    """Everything wrong with a host's project that fits in one line each."""
    problems: list[tuple[str, str]] = []
    raw = value_of(data, "payload_services") or {}
    if raw and value_of(data, "payload_image"):
        return [
            (
                "payload_services",
                "set either payload_image (one service called payload) or "
                "payload_services, not both (set payload_image: null where payload_services is used)",
            )
        ]
    if raw:
        for key, empty in SHORTHAND_SETTINGS.items():
            if value_of(data, key) not in (None, empty):
                problems.append(
                    (
                        key,
                        f"applies to the single-image payload; with payload_services "
                        f"give each service its own '{key.removeprefix('payload_')}' key",
                    )
                )
    services = declared(data)
    if not services:
        return [("payload_image", "required: the payload image, pinned by tag or digest")]
    allow_latest = bool(value_of(data, "payload_allow_latest"))
    payload_dir = value_of(data, "payload_dir") or "/var/lib/robot-payload"
    replaces = {
        entry.partition(":")[2] for entry in value_of(data, "payload_replaces") or [] if entry.startswith("container:")
    }
    names: dict[str, str] = {}
    # The shorthand's one service is checked by the payload_* settings themselves.
    for name, spec in (services if raw else {}).items():
        where = f"payload_services.{key_name(name)}"
        if not re.fullmatch(SERVICE_NAME, name):
            problems.append((where, "service names are letters, digits, . _ - (starting with a letter or digit)"))
        image = spec.get("image")
        if "build" in spec:
            problems.append((f"{where}.build", "robots do not build images; push the image and set image"))
        if image is None:
            problems.append((f"{where}.image", "required: the service's image, pinned by tag or digest"))
        elif isinstance(image, str):
            why = imageref.pinning_problem(image, allow_latest)
            if why:
                problems.append((f"{where}.image", why))
        if spec.get("privileged") and not value_of(data, "payload_allow_privileged"):
            problems.append(
                (
                    f"{where}.privileged",
                    "privileged containers are refused unless "
                    "payload_allow_privileged is true (prefer devices / cap_add)",
                )
            )
        if not value_of(data, "payload_allow_privileged"):
            problems += [
                (
                    f"{where}{key}",
                    f"{what} gives the container root on the robot: refused unless payload_allow_privileged is true",
                )
                for key, what in root_equivalents(spec)
            ]
        container_name = spec.get("container_name")
        if isinstance(container_name, str):
            if container_name in names:
                problems.append(
                    (
                        f"{where}.container_name",
                        f"{container_name!r} is also the container_name of service {names[container_name]}",
                    )
                )
            elif container_name in replaces:
                problems.append(
                    (
                        f"{where}.container_name",
                        f"{container_name!r} is listed in payload_replaces: "
                        "the takeover would stop this project's own container",
                    )
                )
            names.setdefault(container_name, name)
        if "platform" in spec:
            try:
                platforms.parse(spec["platform"])
            except ValueError as error:
                problems.append((f"{where}.platform", str(error)))
        if "profiles" in spec:
            problems.append(
                (
                    f"{where}.profiles",
                    "no profile is activated on the robot, so the service would "
                    "never start (and the health gate could not see it); remove profiles or the service",
                )
            )
        if spec.get("scale") in (0, "0"):
            problems.append((f"{where}.scale", "0 never starts the service; remove the service instead (null)"))
        if spec.get("scale") not in (None, 1) and container_name:
            problems.append((f"{where}.scale", "a fixed container_name allows one container only"))
        for index, source in _bind_sources(spec):
            if source.startswith("/") and _under(source, payload_dir):
                problems.append(
                    (
                        f"{where}.volumes[{index}]",
                        f"{source} is inside {payload_dir} (the releases); mount a path outside it",
                    )
                )
            elif source.startswith("."):
                problems.append(
                    (
                        f"{where}.volumes[{index}]",
                        f"relative path {source} would resolve inside the release directory; use an absolute host path",
                    )
                )
        environment = spec.get("environment")
        if isinstance(environment, dict):
            for key, value in environment.items():
                if value is not None and not isinstance(value, str):
                    problems.append(
                        (
                            f"{where}.environment.{key}",
                            f"expected a string, got {value!r} "
                            "(quote it: YAML reads true/false, null and numbers as other types)",
                        )
                    )
        env_files = spec.get("env_file")
        listed = isinstance(env_files, list)
        for index, entry in enumerate(env_files if listed else [env_files]):
            path = entry.get("path") if isinstance(entry, dict) else entry
            # a secret file may be an env file: the one place in payload_dir it may be read from
            if isinstance(path, str) and (
                not path.startswith("/")
                or (_under(path, payload_dir) and not _under(path, secret_files.directory(payload_dir)))
            ):
                problems.append(
                    (
                        f"{where}.env_file" + (f"[{index}]" if listed else ""),
                        f"{path} would be read from the release directory; use an absolute path outside it",
                    )
                )
    if not raw and not value_of(data, "payload_allow_privileged"):
        volumes = {"volumes": list(value_of(data, "payload_volumes") or [])}
        problems += [
            (
                f"payload_volumes{key.removeprefix('.volumes')}",
                f"{what} gives the container root on the robot: refused unless payload_allow_privileged is true",
            )
            for key, what in root_equivalents(volumes)
        ]
    problems += _preset_problems(data, allow_latest)
    return problems


def _preset_problems(data, allow_latest: bool) -> list[tuple[str, str]]:
    kind = value_of(data, "ros_preset")
    problems = []
    if kind == "ros1" and value_of(data, "ros_roscore"):
        image = value_of(data, "ros_roscore_image")
        if not image:
            problems.append(("ros_roscore_image", "required with ros_roscore: an image with roscore, pinned"))
        else:
            why = imageref.pinning_problem(image, allow_latest)
            if why:
                problems.append(("ros_roscore_image", why))
    if kind == "ros1" and not value_of(data, "ros_roscore") and not value_of(data, "ros_master_uri"):
        problems.append(("ros_master_uri", "required with ros_preset: ros1 unless ros_roscore is true"))
    if value_of(data, "ros_roscore") and kind != "ros1":
        problems.append(("ros_roscore", "needs ros_preset: ros1"))
    bags = value_of(data, "ros_bag_dir")
    if bags and kind not in ("ros1", "ros2"):
        problems.append(("ros_bag_dir", "needs ros_preset: ros1 or ros2"))
    elif bags and bags.rstrip("/") == (value_of(data, "ros_log_dir") or "").rstrip("/"):
        problems.append(("ros_bag_dir", "is ros_log_dir: give the bags a directory of their own"))
    profile = value_of(data, "ros_dds_profile")
    if profile:
        if kind != "ros2":
            problems.append(("ros_dds_profile", "needs ros_preset: ros2"))
        text = dds_profile_text(data)
        if text is None:
            problems.append(("ros_dds_profile", f"no file files/{DDS_DIR}/{profile}"))
        elif dds_vendor(text) is None:
            problems.append(
                (
                    "ros_dds_profile",
                    f"files/{DDS_DIR}/{profile} is neither a Cyclone DDS "
                    "(<CycloneDDS>) nor a Fast DDS (<profiles>/<dds>) XML profile",
                )
            )
    return problems


def host_problems(data: dict, defaults: dict) -> list[tuple[str, str]]:
    """The whole project, built and checked: ``data`` is a host's merged
    settings without those already refused, ``defaults`` the payload's."""
    raw = data.get("payload_services")
    if raw is not None and (not isinstance(raw, dict) or layer_problems(raw)):
        return []  # the layer check has said what is wrong
    problems = project_problems(data)
    if problems:
        return problems
    return schema_problems(compose.project(_Data({**defaults, **data}), "host.invalid"))


class _Data(dict):
    """Attribute access over a plain settings dict (as pyinfra's host.data)."""

    def __getattr__(self, key):
        return self.get(key)
