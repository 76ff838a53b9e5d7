"""What a sensor stream learns from its scans and then holds: laser lines and the ring field's order (`lines`), the
mounting (`mounting`), the vehicle's own returns (`body`), the intensities' full scale (`intensity_scale`) and their
map onto stage 2's training scale (`intensity_match`), all held by one `ScanStream` per stream (`scan_stream`).
Per-scan functions live in pass3d_ros.core.stage1; these modules only decide what a stream keeps and when."""

from pass3d_ros.core.stream.body import BodyHolder
from pass3d_ros.core.stream.lines import LineHolder
from pass3d_ros.core.stream.mounting import MountingHolder
from pass3d_ros.core.stream.scan_stream import Note, PreparedScan, ScanStream

__all__ = ["BodyHolder", "LineHolder", "MountingHolder", "Note", "PreparedScan", "ScanStream"]
