# The flight recorder: what the robot did, written to MCAP files Foxglove and Lichtblick open.
