"""Audit tools for regenerated TAPVid-3D clips.

``python -m pipeline.audit compare REF_DIR NEW_DIR`` scores one output folder against another with
the TAPVid-3D metrics (``pipeline.audit.metrics``), clip by clip and source by source.
"""
