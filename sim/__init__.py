# Simulated robot: the world, noise, metrics and byte-level device emulators.
from __future__ import annotations
