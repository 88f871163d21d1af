"""A test's S3 server configured by explicit options only: no profile, endpoint, proxy or instance
metadata from the environment reaches boto3 or Beam's S3 filesystem."""

from __future__ import annotations

import os

import pytest


def explicit_options_only(env: pytest.MonkeyPatch) -> None:
    """Clear, in ``env`` (a MonkeyPatch), what the environment could configure S3 with, and keep
    requests to 127.0.0.1 off any proxy."""
    for name in ("AWS_PROFILE", "AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3"):
        env.delenv(name, raising=False)
    env.setenv("AWS_EC2_METADATA_DISABLED", "true")
    env.setenv("AWS_CONFIG_FILE", os.devnull)
    env.setenv("AWS_SHARED_CREDENTIALS_FILE", os.devnull)
    env.setenv("NO_PROXY", ",".join(filter(None, [os.environ.get("NO_PROXY"), "127.0.0.1"])))
