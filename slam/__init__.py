# The SLAM core: pose algebra, occupancy grid, scan matching, pose graph; pure (no clock, no I/O).
