"""ROS message codecs that need no rclpy (used by the bag tools and the nodes alike)."""
