"""Aria Digital Twin source: reader (projectaria-tools), units (listing and naming its units),
rectify (pinhole re-rendering and the upright rotation), annotate (the group entry), tracks (one
chunk's candidate clip), source (its Source)."""
