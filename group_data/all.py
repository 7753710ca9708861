"""Defaults for every host: the one place each setting gets its default.

Override any of them in the fleet file (inventories/robots.yaml) under
``all.vars``, a group's ``vars`` or a host.  README.md lists them all.
"""

# Run every operation through sudo (set here, as host data, so that it also
# applies inside conditional blocks; see pyinfra's notes on global arguments).
_sudo = True

# --- SSH ---------------------------------------------------------------------
# Port sshd listens on.
ssh_port = 22
# known_hosts file used for strict host key checking (relative to the
# directory pyinfra runs from).  Add a robot with `ssh-keyscan` after checking
# its fingerprint out of band.
ssh_known_hosts_file = "inventories/known_hosts"
# "yes" refuses unknown or changed host keys.  "accept-new" trusts on first
# use (opt-out, e.g. while bootstrapping); "no" disables checking.
ssh_strict_host_key_checking = "yes"
# Reconnect attempts for robots on flaky links.
ssh_connect_retries = 3
ssh_connect_retry_min_delay = 1
ssh_connect_retry_max_delay = 5

# --- apt (every role that installs packages) ----------------------------------
# Seconds apt and dpkg wait in all for the apt/dpkg locks another process
# holds (unattended-upgrades runs at boot and can take minutes); then the host
# fails naming the lock's holder, with nothing installed.
apt_lock_timeout = 300

# --- Docker engine (roles/docker) ---------------------------------------------
# "docker": Docker CE from Docker's apt repository; "distro": the
# distribution's own docker.io + compose v2 packages.
docker_source = "docker"
# Base URL of Docker's repository (or of a local mirror for air-gapped fleets).
# The distribution ("ubuntu" or "debian") is appended.
docker_repo_url = "https://download.docker.com/linux"
docker_apt_release_channel = "stable"
# Where the repository's signing key is fetched from; None means
# "<docker_repo_url>/<distribution>/gpg".
docker_apt_key_url = None
# Expected OpenPGP fingerprint of that key (Docker's published one).  The key
# file must hold exactly this one key (apt trusts every key of the keyring);
# otherwise the host fails and nothing is installed.  None: no check.
docker_apt_key_fingerprint = "9DC858229FC7DD38854AE2D88D81803C0EBFCD88"
# Optional sha256 of the key file itself.
docker_apt_key_sha256 = None
docker_apt_key_path = "/etc/apt/keyrings/docker.asc"
# Name of the deb822 source: /etc/apt/sources.list.d/<name>.sources
docker_apt_filename = "docker"
# Source and key files left by older install methods; they make apt fail with
# "Conflicting values set for option Signed-By", so they are removed.
docker_apt_legacy_files = [
    "/etc/apt/sources.list.d/docker.list",
    "/etc/apt/sources.list.d/download_docker_com_linux_ubuntu.list",
    "/etc/apt/sources.list.d/download_docker_com_linux_debian.list",
    "/etc/apt/sources.list.d/docker-ce.list",
    "/etc/apt/sources.list.d/docker-ce-stable.list",
    "/etc/apt/trusted.gpg.d/docker.asc",
    "/etc/apt/trusted.gpg.d/docker.gpg",
    "/etc/apt/keyrings/docker.gpg",
]
docker_packages = [
    "docker-ce",
    "docker-ce-cli",
    "containerd.io",
    "docker-buildx-plugin",
    "docker-compose-plugin",
]
# Pin Docker CE to one apt version (e.g. "5:28.5.2-1~ubuntu.24.04~noble");
# applied to docker-ce and docker-ce-cli.  None: whatever is newest.
docker_version = None
# Packages for docker_source: distro.  None: chosen per distribution
# (docker.io + docker-compose-v2 on Ubuntu, docker.io + docker-compose on Debian 13).
docker_distro_packages = None
# Removed before installing Docker CE, only where installed and only while
# Docker CE is not.  Set [] on laptops where you use these deliberately.
docker_obsolete_packages = [
    "docker.io",
    "docker-doc",
    "docker-compose",
    "docker-compose-v2",
    "podman-docker",
    "containerd",
    "runc",
]
# /etc/docker/daemon.json.  Robot-sensible defaults: rotated logs cannot fill
# the disk, and live-restore keeps the payload running across daemon restarts.
docker_daemon_options = {
    "live-restore": True,
    "log-driver": "json-file",
    "log-opts": {"max-size": "10m", "max-file": "3"},
}
# Merged into daemon.json as "registry-mirrors" / "insecure-registries".
docker_registry_mirrors = []
docker_insecure_registries = []
# What a daemon.json change does to the engine: "restarted" or "reloaded".
docker_restart_handler_state = "restarted"
# Seconds Docker has to be active again after a daemon.json change; if it is
# not, the previous daemon.json is put back, Docker restarted with it, and the
# host fails with dockerd's reason.
docker_restart_timeout = 60
docker_service_enabled = True
# Existing users added to the docker group (root-equivalent!).  A user that
# does not exist fails that host; users are never created.
docker_users = []

# --- Sensors and udev (roles/udev) -------------------------------------------
# Sensors given stable names, one generated rules file.  Each entry:
#   name: front_camera            -> /dev/robot/front_camera
#   subsystem: tty | video4linux | hidraw | input | usb | sound
#   serial: "ABC123"              match by serial number, and/or
#   vendor_id: "046d"             match by USB vendor/product id, and/or
#   product_id: "0825"
#   usb_port: "1-2.1"             match by physical USB port (identical devices)
#   group: video                  default per subsystem (dialout for tty, video, ...)
#   mode: "0660"                  world-writable modes are refused
#   symlink: robot/front_camera   under /dev
#   passthrough: true             hand the device to the payload container
sensors = []
udev_rules_file = "/etc/udev/rules.d/70-robot-sensors.rules"
# Static rules files from files/udev/ to install on the host.
udev_vendor_rules = []
udev_allow_world_writable = False

# --- X11 for GUI containers (roles/x11) --------------------------------------
# Whether the host has a display for GUI containers (rviz).
display = False
# The desktop user whose X session the containers use (required with display).
x11_user = None
x11_display = ":0"
# Per-user cookie directories: <dir>/<user>/Xauthority, mounted read-only.
x11_cookie_dir = "/var/lib/robot-x11"

# --- Payload (roles/payload) ------------------------------------------------
# The ROS payload image, pinned by tag or digest.
payload_image = None
payload_allow_latest = False
# Compose project, systemd unit (<name>.service) and directory name.
payload_name = "robot-payload"
payload_dir = "/var/lib/robot-payload"
# "pull": the robot pulls from the registry; "push": the image is sent from
# the operator machine's Docker engine over SSH.
payload_delivery = "pull"
# Start the payload at boot (robots) or only stage it (laptops).
payload_autostart = True
payload_restart_policy = "unless-stopped"
payload_network_mode = "host"
# Extra container environment; values reach the container verbatim.
payload_environment = {}
payload_command = None
# Extra bind mounts, "host_path:container_path[:ro]".
payload_volumes = []
payload_gpu = False
# ROS networking: ROS 2 domain id; set ros_master_uri for ROS 1 instead.
ros_domain_id = 0
ros_master_uri = None
# ROS 1 ROS_HOSTNAME; None: the host's address.
ros_hostname = None
# Health gate: seconds to wait for the payload to become healthy, and for
# images without a HEALTHCHECK, seconds it must run without restarting.
payload_health_timeout = 120
payload_stable_seconds = 10
# Bounds of an update on the robot: seconds for `docker pull` (all tries), and
# seconds to wait for another deploy or rollback of the same robot to finish.
payload_pull_timeout = 300
payload_apply_lock_timeout = 300
# Seconds to wait at boot for the sensors' device links to appear.
payload_device_wait = 30
# Releases kept on the robot (their images are kept too, for offline rollback).
payload_keep_releases = 3
# While this file exists on the robot, updates are refused unless forced.
payload_lock_file = "/run/robot-payload/update.lock"
payload_force = False
# Environment variables (on the operator machine) holding registry
# credentials; never stored in the repository, never printed.
payload_registry_username_env = "PAYLOAD_REGISTRY_USERNAME"
payload_registry_password_env = "PAYLOAD_REGISTRY_PASSWORD"

# --- NVIDIA GPUs (roles/gpu) --------------------------------------------------
# "nvidia": this host has an NVIDIA GPU for containers (payload_gpu implies it).
# The NVIDIA driver must already be loaded; this tool does not install drivers.
gpu = None
# NVIDIA's container toolkit repository (or a local mirror for air-gapped
# fleets with the same layout); the source is <url>/<channel>/deb/<arch>.
gpu_repo_url = "https://nvidia.github.io/libnvidia-container"
gpu_apt_channel = "stable"
# Where the signing key comes from; None means "<gpu_repo_url>/gpgkey".
gpu_apt_key_url = None
# NVIDIA's published key.  The downloaded key must hold exactly this one
# primary key, or the host fails and nothing is installed.
gpu_apt_key_fingerprint = "C95B321B61E88C1809C4F759DDCAE044F796ECB0"
gpu_apt_key_path = "/etc/apt/keyrings/nvidia-container-toolkit.asc"
# /etc/apt/sources.list.d/<name>.sources
gpu_apt_filename = "nvidia-container-toolkit"
# Pin nvidia-container-toolkit to one apt version (e.g. "1.17.8-1"); None: newest.
gpu_toolkit_version = None
# Make "nvidia" Docker's default runtime (daemon.json default-runtime).
gpu_default_runtime = False
# Payload environment for the NVIDIA runtime; capabilities None means
# compute,utility (plus graphics where display is on, for rviz with GL).
gpu_visible_devices = "all"
gpu_driver_capabilities = None
# Run in each payload container after it is healthy; a failure fails the
# release (rolled back).  None: no check.
gpu_check_command = ["nvidia-smi", "-L"]
# The loaded driver announces itself here.  Change it only to test the role
# without a GPU (the lab does); real hosts keep /proc/driver/nvidia/version.
gpu_driver_version_file = "/proc/driver/nvidia/version"

# --- The payload as a compose project (roles/payload/services.py) -----------
# Several services instead of the single payload_image: name -> a Compose
# service (image, command, environment, volumes, ipc, cap_add, ulimits, ...),
# checked against the Compose Specification's JSON Schema before connecting.
# Group and host values merge per service and per key; null removes one.
payload_services = {}
# Containers (names) or compose projects set up another way that the payload
# replaces.  Besides these, any container of the payload's image repositories
# that is not the project's own is taken over: stopped, restart policy "no",
# recorded in the release, and restored if that first release fails.
payload_replaces = []
# Services may not be privileged unless this is true.
payload_allow_privileged = False
# One line for the usual ROS keys: "ros1" (ROS_MASTER_URI, ROS_HOSTNAME,
# optional roscore service) or "ros2" (ROS_DOMAIN_ID, ipc: host, optional
# DDS profile).  None: only ros_domain_id / ros_master_uri as above.
ros_preset = None
# ROS 1: run roscore as a service of the project (image required, pinned).
ros_roscore = False
ros_roscore_image = None
# ROS 2: a DDS profile from files/dds/ (Cyclone DDS or Fast DDS XML), mounted
# read-only with CYCLONEDDS_URI or FASTRTPS_DEFAULT_PROFILES_FILE set.
ros_dds_profile = None
# --- Rollouts in waves (python3 -m roles.rollout) ------------------------------
# This robot is a canary: it is updated in the first wave, before the others.
# When no host sets it, the first --canary N robots of the inventory are.
rollout_canary = False
