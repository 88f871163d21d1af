"""Aria Digital Twin source: reader (projectaria-tools), rectify (pinhole re-rendering and the
upright rotation), annotate (pure NumPy), transform (the Beam edge), bench (speed figures)."""
