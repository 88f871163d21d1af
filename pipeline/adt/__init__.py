"""Aria Digital Twin source: reader (projectaria-tools), rectify (pinhole re-rendering and the
upright rotation), annotate (pure NumPy), source (its Source: units, names, the excerpt)."""
