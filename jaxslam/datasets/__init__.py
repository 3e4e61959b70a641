"""Host-side loaders and simulators (NumPy): CARMEN logs, ROS bags, Victoria Park, the
laser and landmark simulators, the dataset registry (:mod:`jaxslam.datasets.registry`:
names, files, loaders, scoring). Never imported by a kernel."""

__all__ = ["carmen", "carmen_parse", "carmen_read", "geometry", "keyframes", "landmark_sim", "laser_sim", "log_cache", "no_return", "odometry_noise", "odometry_queue", "odometry_repair", "paths", "perturb", "reader", "registry", "relations", "rosbag", "rosbag_messages", "rosbag_write", "trees", "victoria_park", "victoria_park_files"]
