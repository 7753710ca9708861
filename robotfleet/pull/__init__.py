"""Pull mode: robots that converge themselves from signed releases.

- ``record.py``: the release record (release.json), pure;
- ``tree.py``: the deploy tree's content hash and code archive;
- ``waves.py``: waves, failure budget and maintenance windows, pure;
- ``trust.py``: the robot's verified refresh (TUF, python-tuf's ngclient);
  ``tufprivate.py``: the python-tuf private names it needs, in one place;
- ``keys.py``, ``repository.py``: the operator's keys and TUF repository;
- ``channel.py``: where a repository is published (the fleet remote's
  robotfleet/releases branch, or a directory served over HTTPS);
- ``publishing.py``: a release built from the fleet file, the deploy code
  and the roles' pins; ``wheels.py``: the wheelhouse robots install from.

docs/pull.md says how to publish, halt and rotate keys.
"""
