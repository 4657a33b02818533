# The collision monitor: the lidar keeps the robot out of obstacles.
