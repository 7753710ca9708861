"""payloadctl: releases of this robot's payload, run on the robot itself.

A release is a directory releases/<id>/ holding compose.yaml (images pinned
by digest where the registry gave one), spec.json (what the deploy asked
for) and record.json (its state).  `current` and `previous` are symlinks;
the systemd unit runs `current`.  `apply` runs on the robot (started by the
deploy as a transient systemd unit), so a dropped SSH link cannot leave the
robot half-switched:

  download first -> switch -> wait healthy -> keep, or switch back.

Modules by concern: durable (files that survive a power cut), spec (what a
release is, who asks), lifecycle (a release's record, states and every
transition: the only writer of records and pointers), releases (the store,
read only), imageref and images (image references, pulls), health (is it
running well), events (Docker's events that wake the health wait), start
(bring `current` up: here while the unit runs, else through the unit),
lock (one deploy at a time, its token, the update lock),
hold (the lock held for a command), recovery (boot), takeover (containers
set up another way), apply and rollback, results (one structured result a
run), status, cli.  The deploy side imports imageref, spec, lifecycle,
results and takeover, so each rule is written once.

Standard library only, Python >= 3.8 (Ubuntu 20.04).  Shipped to the robot
as one zip application (roles/payload/installed_files.py builds it).
"""
