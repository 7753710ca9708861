"""The operator commands (python3 -m engine ...): status, rollout, generate."""
