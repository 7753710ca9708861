"""The operator commands:

    python3 -m engine enroll INVENTORY [--limit ...] [--fingerprints FILE] [--yes]   # robots' host keys, first
    python3 -m engine status INVENTORY [--limit ...] [--json]
    python3 -m engine rollout INVENTORY [deploy.py] [--canary 1 --batch 25% --max-failed 10%] [-y]
    python3 -m engine generate      # inventories/fleet.schema.json and docs/settings.md from the roles
"""

from __future__ import annotations

import sys

from engine.commands import enroll, generate, rollout, status

COMMANDS = {"enroll": enroll.main, "status": status.main, "rollout": rollout.main, "generate": generate.main}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in COMMANDS:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
