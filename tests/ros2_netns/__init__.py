# ROS 2 face checks run inside a private network namespace (tests/components/ros2/).
