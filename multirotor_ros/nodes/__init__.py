"""The ROS 2 nodes: thin rclpy wrappers around the pure libraries (the only rclpy users)."""
