"""Regenerate and audit the TAPVid-3D benchmark from its source datasets."""

__version__ = "0.1.0"
