"""The benchmark suites of `pass3d_benchmark`. Importing the package registers the `synthetic:` dataset format
(pass3d_ros.synthetic), as the tools package does."""

import pass3d_ros.synthetic  # noqa: F401
