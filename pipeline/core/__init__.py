"""Source-agnostic pieces: camera and SE(3) maths, the clip record, visibility, sampling, config."""
