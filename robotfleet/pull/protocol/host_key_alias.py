"""The name ssh looks the git server up under (HostKeyAlias), so its keys
are pinned to the fleet remote whatever address or port reaches it: the
pull role and a bundle write known_hosts under it
(robotfleet/pull/protocol/agent_files.py's ``known_hosts``), the robot's ssh
asks for it (robotfleet/pull/robot/ssh_options.py)."""

HOST_KEY_ALIAS = "robotfleet-remote"
