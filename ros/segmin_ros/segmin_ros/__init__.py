"""segmin's row follower as a ROS 2 package: the node itself is segmin's (from pip)."""
