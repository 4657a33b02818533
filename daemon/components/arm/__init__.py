# The arm component: a 3-joint pitching arm and a parallel gripper on hobby servos.
