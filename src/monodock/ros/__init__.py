"""ROS 2 nodes: the detector, the docking mission and the simulated robot (they need rclpy)."""
