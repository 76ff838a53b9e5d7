"""Pictures of labeled scans: bird's-eye PNGs (`bev`, with its bitmap `font`) and the rerun viewer's log (`view`)."""
