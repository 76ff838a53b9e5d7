"""What the tests share: the one ROS harness (helpers.ros) and constructed scans (helpers.scans).

Test modules import from here, never from one another; pytest puts test/ on sys.path (setup.cfg `pythonpath`), so
`from helpers.ros import Ros` works under `python -m pytest`, pytest-xdist workers and `colcon test` alike.
"""
