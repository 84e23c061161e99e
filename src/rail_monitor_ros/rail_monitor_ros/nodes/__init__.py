"""ROS 2 nodes: one thin module per node (messages <-> arrays <-> core)."""
