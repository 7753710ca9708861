"""The one place python-tuf's private names are used, each with why.

Checked against the installed python-tuf by tests/unit/test_pyinfra_private.py
(robotfleet/pyinfra_private.py pins them: a tuf release that renames one
fails that test, not a robot in the field).

- ``Updater._trusted_set.reference_time``: ngclient checks every expiry
  against the time its TrustedMetadataSet was made (the system clock), with
  no public way to give another.  A robot without an RTC boots in 1970 or
  at its last saved time; the clock rule (trust.py) checks expiry against
  max(system clock, last trusted time) instead, so it sets this before
  refresh().
"""

from __future__ import annotations

import datetime


def set_reference_time(updater, moment: datetime.datetime) -> None:
    """Make ``updater`` (a fresh tuf.ngclient.Updater) check expiry against ``moment``."""
    trusted = updater._trusted_set
    if not isinstance(getattr(trusted, "reference_time", None), datetime.datetime):
        raise RuntimeError(
            "python-tuf no longer keeps Updater._trusted_set.reference_time: "
            "robotfleet/pull/robot/tufprivate.py needs updating for this tuf version"
        )
    trusted.reference_time = moment
