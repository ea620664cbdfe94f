"""The model: rotations, the robot's kinematics, the camera, the belief (EKF) and
the motion limits."""
