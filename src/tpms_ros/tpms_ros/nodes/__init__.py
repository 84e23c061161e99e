"""ROS nodes of the road domain: one thin module per node, plus their raw wheel-speed decoder."""
