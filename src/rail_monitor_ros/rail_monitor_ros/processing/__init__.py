"""Node logic, ROS-free: one processor per node, run by the node and by the offline engine."""
