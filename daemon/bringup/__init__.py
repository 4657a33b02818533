# Bring-up helpers for a new robot: `arbiterd test-motors` (daemon/bringup/cli.py).
