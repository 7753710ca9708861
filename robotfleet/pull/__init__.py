"""Pull mode: robots that converge themselves from signed releases (docs/guides/pull.md;
how it works: docs/explanations/pull.md).

Three layers, held by import-linter (pyproject.toml):

- ``protocol/``: what both sides read and write: the release record, the
  reports and where they live, waves and windows, the deploy tree's hash,
  the agent's files and configuration on a robot, a robot's data;
- ``robot/``: what runs on the robot: the agent, its transport, the TUF
  verification, why it refuses, and what it trusts between checks, the decision, preparing
  (and prefetching, before the window) and running a release's converge;
- ``operator/``: what runs on the operator's machine: keys, the TUF
  repository and its root ceremony, publishing, wheels, bundles, gitolite's rules, the pull
  role's install of the agent, the commands' shared options.

The robot's side and the operator's side never import each other.
``agent.py`` here is an entry point only: its name is in every robot's
robot-pull.service.
"""
