# The fleet: robots publishing to one operator over Zenoh (docs/fleet.md).
