"""The robot: its description (URDF spec), batched forward kinematics, IK, SE(3) helpers."""
