"""Scoring the pipeline: offline over datasets, live through the ROS nodes, and reports (pictures: `drawing`)."""
