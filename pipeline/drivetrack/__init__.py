"""DriveTrack clips from Waymo Open Dataset v2 (Parquet), as the TAPVid-3D release built them."""
