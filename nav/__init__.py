# Navigation algorithms: costmap, grid planner, path following; pure, clock-free, no I/O.
