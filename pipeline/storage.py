"""Remote inputs and outputs (``gs://``, ``s3://``, ...) through Beam's FileSystems.

``check_scheme`` turns a path whose filesystem is missing into a one-line hint (the extra to
install) instead of a traceback; ``use_options`` hands the run's pipeline options
(``--s3_endpoint_url``, ``--s3_region_name``, ...) to FileSystems in each process that opens files;
and lets Beam write empty files to S3.
"""

from __future__ import annotations

import importlib.util

from apache_beam.io.filesystem import BeamIOError, FileSystem
from apache_beam.io.filesystems import FileSystems
from apache_beam.options.pipeline_options import PipelineOptions

# The extra of this package each remote scheme needs.
EXTRAS = {"gs": "gcp", "s3": "aws"}
# Beam registers its S3 filesystem without boto3, which it imports only when it opens a file.
S3_CLIENT = "boto3"


class StorageError(ValueError):
    """A path no usable Beam filesystem can open; the message is one line saying what to do."""


def check_scheme(path: str) -> None:
    """Raise StorageError unless Beam has a working filesystem for ``path`` (local paths always do)."""
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
    raise StorageError(
        f"no usable filesystem for {path}: Beam opens local paths and "
        f"{', '.join(s + '://' for s in known)} (each with its own dependencies)"
    )


def use_options(options: PipelineOptions | None) -> None:
    """Give FileSystems in this process the run's options (S3 endpoint, credentials, region, ...) and
    let it write empty files to S3. Beam does the former for the DirectRunner's workers, not for the
    main process (which lists units and writes before the pipeline exists) nor for Dask's workers."""
    if options is not None:
        FileSystems.set_options(options)
        allow_empty_s3_objects()


def allow_empty_s3_objects() -> None:
    """Let Beam write empty files to S3 (apache/beam#21369): its uploader completes an empty file's
    multipart upload with no part, which S3 refuses (MalformedXML); send one empty part first."""
    try:
        from apache_beam.io.aws.s3io import S3Uploader
    except ImportError:
        return
    finish = S3Uploader.finish
    if getattr(finish, "sends_a_part", False):
        return

    def finish_with_a_part(self) -> None:
        if not self.parts and not self.buffer:
            self._write_to_s3(b"")
        finish(self)

    finish_with_a_part.sends_a_part = True
    S3Uploader.finish = finish_with_a_part
