"""`follow ros2`: the ROS 2 node. The only package of `follow` that imports rclpy (its
modules `node`, `messages` and `cli` do so when they are run, never on import of
`follow`); `gate` holds its safety logic without ROS so it is tested everywhere."""
