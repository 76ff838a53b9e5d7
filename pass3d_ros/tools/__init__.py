"""The command-line tools. Importing the package registers every dataset format a `--data` spec can name: the data
layer's own, and `synthetic:` from pass3d_ros.synthetic (above the data layer, so it registers itself)."""

import pass3d_ros.synthetic  # noqa: F401
