"""roles/payload: the ROS payload as releases run by a systemd unit.

The deploy computes the compose document from host data (and what other
roles add to its services through ``hooks``); when it differs from the
robot's current release (or the unit changed, or the payload is down), it
hands the spec to payloadctl on the robot, which pulls first, switches,
waits for health and rolls back on failure.  Nothing changes otherwise.

- settings.py: the settings; services.py, presets.py, compose.py: the
  compose document; problems.py: what is refused before connecting;
- steps.py: the deploy's steps; release.py: the release on the robot;
  credentials.py, login.py, image_transfer.py, transferred_images.py,
  registry.py: each registry's own credentials, registry login, an image
  sent over SSH for payload_delivery push (image_transfer.py; the images
  beyond the first: transferred_images.py); takeover_plan.py: what the release
  will take over, said before it is done; dds_profile.py: the DDS profile file;
- installed_files.py (payloadctl as one zip application, the systemd unit),
  payloadctl/ (the robot-side program), payload.service.j2: what runs on the robot;
- report.py: its columns in status, what a rollout waits for; pins.py: the
  image digests a pull release binds (robotfleet publish); digests.py: those
  digests applied when the robot runs the release (payload_image_pins);
  hold.py, window_switch.py: its parts in a pull robot's converge (the apply
  lock held for the run; a release prepared before its window, switched in it;
  its images pulled or loaded from media: image_helper, payloadctl/agent_images.py).
"""

from robotfleet.role import Role
from roles.payload import credentials, hold, pins, report, secret_files, settings, steps, window_switch
from roles.payload.installed_files import HELPER
from roles.payload.release import rollback_release


def held_secrets(data) -> list[str]:
    """The registry passwords and the secret files' contents (masked in output)."""
    return credentials.secrets(data) + secret_files.secrets(data)


ROLE = Role(
    name="payload",
    doc="The ROS payload: image pulled or pushed, compose file, a systemd unit, health-gated releases with rollback.",
    settings=settings.SETTINGS,
    reads=steps.declare_reads,
    steps=steps.deploy_payload,
    rules=settings.rules,
    renamed=settings.RENAMED,
    secrets=held_secrets,
    status=report.STATUS,
    rollout=report.ROLLOUT,
    pins=pins.PINS,
    hold=hold.HOLD,
    switch=window_switch.SWITCH,
    image_helper=(HELPER,),
)

__all__ = ["ROLE", "rollback_release"]
