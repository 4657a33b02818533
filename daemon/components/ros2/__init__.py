# The native ROS 2 face: arbiterd as a ROS 2 node of its own over DDS ([ros2], docs/ros2.md).
