# The navigation component: go to a goal pose, or follow a path, on a costmap from the lidar.
