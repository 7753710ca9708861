"""What runs on the operator's machine for pull mode: keys, the release
repository, publishing, wheels, first-boot bundles, gitolite's rules and the
agent's install by a push deploy.  Never imports the robot's side."""
