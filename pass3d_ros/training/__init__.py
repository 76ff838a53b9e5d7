"""Stage-2 training: samples from stage-1 proposals of labelled scans, the losses, validation, the trainer."""
