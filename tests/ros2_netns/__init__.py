# ROS 2 face checks that run inside a private network namespace (tests/test_ros2_face.py).
