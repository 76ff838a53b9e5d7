"""Scoring the pipeline: offline over datasets, live through the ROS nodes, reports and bird's-eye views."""
