"""Defaults for every host, assembled from the settings the engine and the
roles declare (robotfleet/fleet/connection.py, roles/*/settings.py; listed in
docs/reference/settings.md).  Override any of them in the fleet file."""

from robotfleet.deploy_roles import group_data

# Run every operation through sudo (host data, so that it also applies
# inside conditional blocks; see pyinfra's notes on global arguments).
_sudo = True

globals().update(group_data("all"))
