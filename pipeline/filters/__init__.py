"""Track filters shared by all sources: statistics per track, then thresholded verdicts."""
