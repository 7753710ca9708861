"""The operator's pull mode commands (docs/guides/pull.md): publish, halt,
export, keys, bundle, pull-enroll, and the pull parts of status and rollout."""
