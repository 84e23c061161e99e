"""The road nodes' logic as ROS-free processors (``vehicle_monitor_common.processing``)."""
