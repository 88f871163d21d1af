"""Regenerate and audit the TAPVid-3D benchmark from its source datasets."""

import logging

__version__ = "0.1.0"


class _BeamImportNoise(logging.Filter):
    """Drops the warning Beam logs on import when its optional GCP client (apitools) is absent:
    nothing here uses BigQuery, and it would otherwise greet every command."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("apitools not found")


logging.getLogger().addFilter(_BeamImportNoise())
