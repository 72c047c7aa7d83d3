"""segmin on ROS 2: the row-follower node (rclpy), its parameters and its command line."""
