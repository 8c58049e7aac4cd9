"""ROS 2 message types for servo_app's data leaving the machine (MCAP logs, Zenoh): CDR via rosbags."""
