"""Defaults that differ for the robots group, from the roles' declarations
(a setting's `groups=`); the rest come from all.py."""

from robotfleet.deploy_roles import group_data

globals().update(group_data("robots"))
