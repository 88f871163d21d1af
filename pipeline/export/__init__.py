"""Writing clips, audit tables, manifests and run records; validating clips."""
