"""Remote inputs and outputs (``gs://``, ``s3://``, ...) through Beam's FileSystems.

``check_scheme`` turns a path whose filesystem is missing into a one-line hint (the extra to
install) instead of a traceback; ``use_options`` hands the run's pipeline options
(``--s3_endpoint_url``, ``--s3_region_name``, ...) to FileSystems in each process that opens files,
lets Beam write empty files to S3 and makes its S3 calls share one boto3 client.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from typing import Any

from apache_beam.io.filesystem import BeamIOError, FileSystem
from apache_beam.io.filesystems import FileSystems
from apache_beam.options.pipeline_options import PipelineOptions, S3Options

from pipeline.io.http import scrub

# The extra of this package each remote scheme needs.
EXTRAS = {"gs": "gcp", "s3": "aws"}
# Beam registers its S3 filesystem without boto3, which it imports only when it opens a file.
S3_CLIENT = "boto3"
# The options Beam builds its boto3 S3 client from (apache_beam.io.aws.clients.s3.boto3_client).
S3_CLIENT_OPTIONS = (
    "s3_access_key_id",
    "s3_secret_access_key",
    "s3_session_token",
    "s3_endpoint_url",
    "s3_disable_ssl",
    "s3_region_name",
    "s3_api_version",
    "s3_verify",
)
# Set on a library method this module replaced (``replace_method_once``), so a second call keeps it.
REPLACED_MARK = "replaced_by_tapvid3d_storage"


class StorageError(ValueError):
    """A path no usable Beam filesystem can open; the message is one line saying what to do."""


def check_scheme(path: str, also: tuple[str, ...] = ()) -> None:
    """Raise StorageError unless Beam has a working filesystem for ``path`` (local paths always do);
    ``also``: schemes the caller reads itself (``http``, ``https``), named among those that work."""
    scheme = FileSystems.get_scheme(path)
    if scheme is None:
        return
    try:
        FileSystems.get_filesystem(path)
        usable = scheme != "s3" or importlib.util.find_spec(S3_CLIENT) is not None
    except (ValueError, BeamIOError):
        usable = False
    if usable:
        return
    extra = EXTRAS.get(scheme)
    if extra:
        raise StorageError(
            f"{scheme}:// paths need the {extra} extra: pip install 'tapvid3d-pipeline[{extra}]' "
            f"(pip install -e '.[{extra}]' in a checkout), on the workers too"
        )
    known = sorted({*EXTRAS, *(fs.scheme() for fs in FileSystem.get_all_subclasses() if fs.scheme())})
    beam = (
        f"Beam opens local paths and {', '.join(s + '://' for s in known)} (each with its own dependencies)"
    )
    own = f"; {' and '.join(s + '://' for s in also)} are read directly" if also else ""
    raise StorageError(f"no usable filesystem for {scrub(path)}: {beam}{own}")


def use_options(options: PipelineOptions | None) -> None:
    """Give FileSystems in this process the run's options (S3 endpoint, credentials, region, ...) and
    let it write empty files to S3 with one shared client. Beam does the former for the
    DirectRunner's workers, not for the main process (which lists units and writes before the
    pipeline exists) nor for Dask's workers."""
    if options is not None:
        FileSystems.set_options(options)
        allow_empty_s3_objects()
        share_s3_clients()


def allow_empty_s3_objects() -> None:
    """Let Beam write empty files to S3 (apache/beam#21369): its uploader completes an empty file's
    multipart upload with no part, which S3 refuses (MalformedXML); send one empty part first."""
    try:
        from apache_beam.io.aws.s3io import S3Uploader
    except ImportError:
        return

    def with_a_part(finish: Callable[[S3Uploader], None]) -> Callable[[S3Uploader], None]:
        def finish_with_a_part(self: S3Uploader) -> None:
            if not self.parts and not self.buffer:
                self._write_to_s3(b"")
            finish(self)

        return finish_with_a_part

    replace_method_once(S3Uploader, "finish", with_a_part)


def share_s3_clients() -> None:
    """Build Beam's boto3 S3 client once per process and options. Beam makes a new boto3 session
    and client for every S3 call (each open, exists, rename, delete), and each new session parses
    botocore's service models again: about 0.35 s of CPU per file operation, 6 of every 7 seconds
    of a small run against S3. boto3's clients are thread-safe; each Beam client keeps its own
    download position, copied fresh from the first one built."""
    try:
        from apache_beam.io.aws.clients.s3.boto3_client import Client
    except ImportError:
        return
    built: dict[tuple, dict] = {}

    def once_per_options(build: Callable[[Client, Any], None]) -> Callable[[Client, Any], None]:
        def build_once(self: Client, options: Any) -> None:
            key = (os.getpid(), *s3_client_options(options))
            state = built.get(key)
            if state is None:
                build(self, options)
                built[key] = dict(vars(self))
            else:
                vars(self).update(state)

        return build_once

    replace_method_once(Client, "__init__", once_per_options)


def replace_method_once(owner: type, name: str, wrap: Callable[[Any], Callable[..., None]]) -> None:
    """Put ``wrap(method)`` in place of the library method ``owner.<name>``, unless this module
    already replaced it in this process (the replacement carries the attribute ``REPLACED_MARK``)."""
    method = getattr(owner, name)
    if getattr(method, REPLACED_MARK, False):
        return
    replacement = wrap(method)
    setattr(replacement, REPLACED_MARK, True)
    setattr(owner, name, replacement)


def s3_client_options(options) -> tuple:
    """The values of S3_CLIENT_OPTIONS in ``options`` (PipelineOptions or a dict, as Beam takes)."""
    if isinstance(options, PipelineOptions):
        view = options.view_as(S3Options)
        return tuple(repr(getattr(view, name, None)) for name in S3_CLIENT_OPTIONS)
    return tuple(repr(options.get(name)) for name in S3_CLIENT_OPTIONS)
