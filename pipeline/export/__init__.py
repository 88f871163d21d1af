"""Writing clips, audit tables, manifests and runs' provenance; validating clips."""
