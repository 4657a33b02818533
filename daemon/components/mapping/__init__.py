# The mapping component: a map from the lidar and odometry, and the robot's pose in it.
