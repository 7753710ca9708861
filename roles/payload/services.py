"""The payload as a compose project of several services (pure functions).

- ``merge_layers``: group and host ``payload_services`` merge per service and
  per key (a host restates only what differs; ``null`` removes a service or
  a key), the way users of Ansible's ``combine(recursive=True)`` expect.
- ``declared``: the services a host runs (``payload_services``, or the
  single-image shorthand as one service called ``payload``).
- ``preset``: what ``ros_preset`` adds (ROS 1 / ROS 2 environment, ``ipc``,
  a DDS profile, a roscore service).
- ``service``: one service of the compose document, our defaults under the
  user's keys.
- ``problems``: every refusal, as (field, message) pairs, including the
  Compose Specification's published JSON Schema (shipped by the
  check-jsonschema package with its licence; never hand-written here).
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import json
import re
import xml.etree.ElementTree as ElementTree
from functools import lru_cache
import importlib.util
from pathlib import Path

from roles import imageref

SHORTHAND = "payload"
SERVICE_NAME = r"[a-zA-Z0-9][a-zA-Z0-9._-]*"
FILES_DIR = Path(__file__).resolve().parents[2] / "files"
DDS_DIR = "dds"
CONTAINER_DDS_DIR = "/etc/ros/dds"
PROFILE_LABEL = "io.robot-fleet.dds-profile"
# The settings that only describe the shorthand's one service.
SHORTHAND_SETTINGS = {"payload_command": None, "payload_volumes": [], "payload_gpu": False}


# --- merging ----------------------------------------------------------------


def merge(base, override):
    """Mappings merge recursively, None removes a key, anything else replaces."""
    if not isinstance(base, dict) or not isinstance(override, dict):
        return copy.deepcopy(override)
    result = copy.deepcopy(base)
    for key, value in override.items():
        if value is None:
            result.pop(key, None)
        else:
            result[key] = merge(result.get(key), value)
    return result


def merge_layers(layers: list) -> dict:
    """payload_services of all.vars < group vars < host, merged per service."""
    merged: dict = {}
    for layer in layers:
        value = (layer or {}).get("payload_services")
        if isinstance(value, dict):
            merged = merge(merged, value)
    return merged


def merge_into(data: dict, layers: list) -> None:
    """The fleet file's hook: a host's payload_services is the merge of its layers."""
    if any(isinstance((layer or {}).get("payload_services"), dict) for layer in layers):
        data["payload_services"] = merge_layers(layers)


# --- the services a host runs --------------------------------------------------


def _get(data, key, default=None):
    getter = getattr(data, "get", None)
    value = getter(key, default) if getter else getattr(data, key, default)
    return default if value is None and default is not None else value


def declared(data) -> dict[str, dict]:
    """name -> the service as the user wrote it (before our defaults)."""
    services = _get(data, "payload_services") or {}
    if services:
        return {name: dict(spec or {}) for name, spec in services.items()}
    image = _get(data, "payload_image")
    return {SHORTHAND: {"image": image}} if image else {}


def environment_mapping(value) -> dict:
    """Compose's environment, list form ("A=1") or mapping, as a mapping."""
    if isinstance(value, dict):
        return dict(value)
    result = {}
    for item in value or []:
        key, sep, rest = str(item).partition("=")
        result[key] = rest if sep else None
    return result


def sensor_services(data, services: dict[str, dict]) -> dict[str, list[str]]:
    """service -> device paths: a sensor goes to the services it names, by
    default to every service that asked for devices, or the single payload."""
    from roles.udev import rules

    asking = [name for name, spec in services.items() if "devices" in spec]
    default = asking or (list(services) if len(services) == 1 else [])
    result: dict[str, list[str]] = {name: [] for name in services}
    for sensor in _get(data, "sensors") or []:
        if not sensor.get("passthrough", True):
            continue
        for name in sensor.get("services") or default:
            if name in result:
                result[name].append(f"/dev/{rules.symlink(sensor)}")
    return result


# --- ROS presets ----------------------------------------------------------------


def dds_vendor(xml_text: str) -> str | None:
    """'cyclonedds' or 'fastdds' by the profile's root element, else None."""
    try:
        root = ElementTree.fromstring(xml_text)
    except ElementTree.ParseError:
        return None
    tag = root.tag.rsplit("}", 1)[-1]
    if tag == "CycloneDDS":
        return "cyclonedds"
    if tag in ("profiles", "dds"):
        return "fastdds"
    return None


def dds_profile_host_path(data) -> str:
    return f"/etc/{_get(data, 'payload_name')}/{_get(data, 'ros_dds_profile')}"


def dds_profile_text(data, files_dir: Path = FILES_DIR) -> str | None:
    name = _get(data, "ros_dds_profile")
    if not name:
        return None
    try:
        return (files_dir / DDS_DIR / name).read_text()
    except OSError:
        return None


def preset(data, address: str, files_dir: Path = FILES_DIR) -> dict:
    """What ros_preset adds: environment (set / dropped), keys every service
    gets unless it sets them, volumes, labels, and extra services."""
    kind = _get(data, "ros_preset")
    result: dict = {"environment": {}, "drop": [], "keys": {}, "volumes": [], "labels": {}, "extra": {}}
    if kind == "ros1":
        roscore = bool(_get(data, "ros_roscore"))
        host_network = _get(data, "payload_network_mode") == "host"
        master = _get(data, "ros_master_uri") or (
            f"http://{'localhost' if host_network else 'roscore'}:11311" if roscore else None
        )
        if master:
            result["environment"]["ROS_MASTER_URI"] = master
        result["environment"]["ROS_HOSTNAME"] = _get(data, "ros_hostname") or address
        result["drop"] = ["ROS_DOMAIN_ID"]
        if roscore:
            result["extra"]["roscore"] = {"image": _get(data, "ros_roscore_image"), "command": ["roscore"]}
            result["keys"]["depends_on"] = ["roscore"]
    elif kind == "ros2":
        result["environment"]["ROS_DOMAIN_ID"] = str(_get(data, "ros_domain_id", 0))
        result["drop"] = ["ROS_MASTER_URI", "ROS_HOSTNAME"]
        # Shared-memory transports (Fast DDS SHM, iceoryx) need one IPC namespace.
        result["keys"]["ipc"] = "host"
        text = dds_profile_text(data, files_dir)
        if text is not None:
            name = _get(data, "ros_dds_profile")
            inside = f"{CONTAINER_DDS_DIR}/{name}"
            if dds_vendor(text) == "cyclonedds":
                result["environment"]["CYCLONEDDS_URI"] = f"file://{inside}"
                result["environment"]["RMW_IMPLEMENTATION"] = "rmw_cyclonedds_cpp"
            else:
                result["environment"]["FASTRTPS_DEFAULT_PROFILES_FILE"] = inside
                result["environment"]["FASTDDS_DEFAULT_PROFILES_FILE"] = inside
                result["environment"]["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
            result["volumes"].append(f"{dds_profile_host_path(data)}:{inside}:ro")
            # A changed profile is a new release: the containers must reread it.
            result["labels"][PROFILE_LABEL] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return result


# --- one service of the document ------------------------------------------------


def _unique(items: list) -> list:
    seen, result = set(), []
    for item in items:
        key = json.dumps(item, sort_keys=True)
        if key not in seen:
            seen.add(key)
            result.append(item)
    return result


def service(base: dict, user: dict, extra: dict, name: str) -> dict:
    """``base`` is the single-service builder's result (restart, network,
    ROS/X11 environment, label, sensors); the preset and the user's keys go
    on top: environment and labels merge, volumes and devices add up, any
    other key of the user's replaces ours."""
    result = copy.deepcopy(base)
    env = result.get("environment", {})
    for key in extra["drop"]:
        env.pop(key, None)
    env.update(extra["environment"])
    env.update(environment_mapping(user.get("environment")))
    result["environment"] = env
    # Compose's labels, like its environment, may be a list of "key=value".
    result["labels"] = {**environment_mapping(user.get("labels")), **extra["labels"], **result.get("labels", {})}
    volumes = list(user.get("volumes") or []) + result.get("volumes", []) + extra["volumes"]
    devices = list(user.get("devices") or []) + result.get("devices", [])
    for key, value in user.items():
        if key not in ("environment", "labels", "volumes", "devices"):
            result[key] = copy.deepcopy(value)
    for key, value in extra["keys"].items():
        if key not in user and not (key == "depends_on" and name in extra["extra"]):
            result[key] = copy.deepcopy(value)
    if volumes:
        result["volumes"] = _unique(volumes)
    if devices:
        result["devices"] = _unique(devices)
    else:
        result.pop("devices", None)
    return result


def images(data) -> list[str]:
    """Every image the project runs (the preset's roscore included)."""
    refs = [spec.get("image") for spec in declared(data).values()]
    if _get(data, "ros_preset") == "ros1" and _get(data, "ros_roscore"):
        refs.append(_get(data, "ros_roscore_image"))
    return [r for r in dict.fromkeys(refs) if isinstance(r, str)]


def repositories(data) -> list[str]:
    result = []
    for ref in images(data):
        try:
            result.append(imageref.parse(ref).repository)
        except ValueError:
            continue
    return sorted(set(result))


# --- refusals --------------------------------------------------------------------


@lru_cache(maxsize=1)
def compose_schema() -> dict:
    """The Compose Specification's JSON Schema as check-jsonschema vendors it."""
    return json.loads(compose_schema_path().read_text())


def compose_schema_path() -> Path:
    """Found without importing check_jsonschema (its CLI imports take a second)."""
    spec = importlib.util.find_spec("check_jsonschema")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("check-jsonschema is not installed (pip install -e .): it carries the Compose schema")
    return Path(list(spec.submodule_search_locations)[0]) / "builtin_schemas" / "vendor" / "compose-spec.json"


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
            problems.append((f"payload_services{_field(path[1:] if path[:1] == ['services'] else path)}",
                             f"Compose Specification: {error.message}"))
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
    raw = _get(data, "payload_services") or {}
    if raw and _get(data, "payload_image"):
        return [("payload_services", "set either payload_image (one service called payload) or "
                 "payload_services, not both (set payload_image: null where payload_services is used)")]
    if raw:
        for key, empty in SHORTHAND_SETTINGS.items():
            if _get(data, key) not in (None, empty):
                problems.append((key, f"applies to the single-image payload; with payload_services "
                                 f"give each service its own '{key.removeprefix('payload_')}' key"))
    services = declared(data)
    if not services:
        return [("payload_image", "required: the payload image, pinned by tag or digest")]
    allow_latest = bool(_get(data, "payload_allow_latest"))
    payload_dir = _get(data, "payload_dir") or "/var/lib/robot-payload"
    replaces = set(_get(data, "payload_replaces") or [])
    names: dict[str, str] = {}
    # The shorthand's one service is checked by the payload_* settings themselves.
    for name, spec in (services if raw else {}).items():
        where = f"payload_services.{name}"
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
        if spec.get("privileged") and not _get(data, "payload_allow_privileged"):
            problems.append((f"{where}.privileged", "privileged containers are refused unless "
                             "payload_allow_privileged is true (prefer devices / cap_add)"))
        container_name = spec.get("container_name")
        if isinstance(container_name, str):
            if container_name in names:
                problems.append((f"{where}.container_name",
                                 f"{container_name!r} is also the container_name of service {names[container_name]}"))
            elif container_name in replaces:
                problems.append((f"{where}.container_name", f"{container_name!r} is listed in payload_replaces: "
                                 "the takeover would stop this project's own container"))
            names.setdefault(container_name, name)
        if "profiles" in spec:
            problems.append((f"{where}.profiles", "no profile is activated on the robot, so the service would "
                             "never start (and the health gate could not see it); remove profiles or the service"))
        if spec.get("scale") in (0, "0"):
            problems.append((f"{where}.scale", "0 never starts the service; remove the service instead (null)"))
        if spec.get("scale") not in (None, 1) and container_name:
            problems.append((f"{where}.scale", "a fixed container_name allows one container only"))
        for index, source in _bind_sources(spec):
            if source.startswith("/") and _under(source, payload_dir):
                problems.append((f"{where}.volumes[{index}]", f"{source} is inside {payload_dir} (the releases); "
                                 "mount a path outside it"))
            elif source.startswith("."):
                problems.append((f"{where}.volumes[{index}]", f"relative path {source} would resolve inside "
                                 "the release directory; use an absolute host path"))
        environment = spec.get("environment")
        if isinstance(environment, dict):
            for key, value in environment.items():
                if value is not None and not isinstance(value, str):
                    problems.append((f"{where}.environment.{key}", f"expected a string, got {value!r} "
                                     "(quote it: YAML reads yes/no/on/off and numbers as other types)"))
        env_files = spec.get("env_file")
        for index, entry in enumerate(env_files if isinstance(env_files, list) else [env_files]):
            path = entry.get("path") if isinstance(entry, dict) else entry
            if isinstance(path, str) and (not path.startswith("/") or _under(path, payload_dir)):
                problems.append((f"{where}.env_file", f"{path} would be read from the release directory; "
                                 "use an absolute path outside it"))
    problems += _sensor_problems(data, services, bool(raw))
    problems += _preset_problems(data, allow_latest)
    return problems


def _sensor_problems(data, services: dict, multi: bool) -> list[tuple[str, str]]:
    problems = []
    asking = [name for name, spec in services.items() if "devices" in spec]
    for index, sensor in enumerate(_get(data, "sensors") or []):
        if not isinstance(sensor, dict) or not sensor.get("passthrough", True):
            continue
        named = sensor.get("services")
        for name in named or []:
            if name not in services:
                problems.append((f"sensors[{index}].services", f"no service called {name!r} "
                                 f"(services: {', '.join(services)})"))
        if not named and multi and len(services) > 1 and not asking:
            problems.append((f"sensors[{index}]", "name the service(s) that use it (services: [...]); "
                             "no service asks for devices"))
    return problems


def _preset_problems(data, allow_latest: bool) -> list[tuple[str, str]]:
    kind = _get(data, "ros_preset")
    problems = []
    if kind == "ros1" and _get(data, "ros_roscore"):
        image = _get(data, "ros_roscore_image")
        if not image:
            problems.append(("ros_roscore_image", "required with ros_roscore: an image with roscore, pinned"))
        else:
            why = imageref.pinning_problem(image, allow_latest)
            if why:
                problems.append(("ros_roscore_image", why))
    if kind == "ros1" and not _get(data, "ros_roscore") and not _get(data, "ros_master_uri"):
        problems.append(("ros_master_uri", "required with ros_preset: ros1 unless ros_roscore is true"))
    if _get(data, "ros_roscore") and kind != "ros1":
        problems.append(("ros_roscore", "needs ros_preset: ros1"))
    profile = _get(data, "ros_dds_profile")
    if profile:
        if kind != "ros2":
            problems.append(("ros_dds_profile", "needs ros_preset: ros2"))
        text = dds_profile_text(data)
        if text is None:
            problems.append(("ros_dds_profile", f"no file files/{DDS_DIR}/{profile}"))
        elif dds_vendor(text) is None:
            problems.append(("ros_dds_profile", f"files/{DDS_DIR}/{profile} is neither a Cyclone DDS "
                             "(<CycloneDDS>) nor a Fast DDS (<profiles>/<dds>) XML profile"))
    return problems


def layer_problems(value) -> list[tuple[str, str]]:
    """One layer's payload_services: a mapping of service name -> mapping (or
    null to remove it).  Keys are checked on the merged project."""
    if not isinstance(value, dict):
        return [("", "expected a mapping of service name -> compose service")]
    problems = []
    for name, spec in value.items():
        if not isinstance(name, str) or not re.fullmatch(SERVICE_NAME, name):
            problems.append((f".{name}", "service names are letters, digits, . _ - (starting with a letter or digit)"))
        elif spec is not None and not isinstance(spec, dict):
            problems.append((f".{name}", "expected a mapping of compose keys (or null to remove the service)"))
    return problems


def host_problems(data) -> list[tuple[str, str]]:
    """settings.check_host's hook: the whole project, built and checked."""
    from roles.payload import compose

    raw = _get(data, "payload_services")
    if raw is not None and (not isinstance(raw, dict) or layer_problems(raw)):
        return []  # the layer check has said what is wrong
    problems = project_problems(data)
    if problems:
        return problems
    return schema_problems(compose.project(_Data(data), "host.invalid", gui=None))


class _Data(dict):
    """Attribute access over a plain settings dict, with group_data defaults."""

    def __getattr__(self, key):
        if key in self:
            return self[key]
        return _defaults().get(key)


@lru_cache(maxsize=1)
def _defaults() -> dict:
    from roles.fleet import read_group_data

    return read_group_data().get("all", {})
