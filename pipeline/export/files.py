"""Atomic, idempotent writes through Beam's FileSystems (local, GCS, S3, HDFS alike)."""

from __future__ import annotations

import uuid

from apache_beam.io.filesystem import CompressionTypes
from apache_beam.io.filesystems import FileSystems


def write_atomic(path: str, data: bytes) -> None:
    """Write ``data`` to a hidden temporary file beside ``path``, then rename it into place.

    A crash leaves either the old file, the new file, or a hidden ``.partial`` file that
    no reader lists; never a truncated ``path``.
    """
    folder, _, name = path.rpartition("/")
    temporary = f"{folder}/.{name}.partial-{uuid.uuid4().hex}" if folder else f".{name}.partial"
    try:
        with FileSystems.create(temporary, compression_type=CompressionTypes.UNCOMPRESSED) as out:
            out.write(data)
        if FileSystems.exists(path):
            FileSystems.delete([path])
        FileSystems.rename([temporary], [path])
    except BaseException:
        if FileSystems.exists(temporary):
            FileSystems.delete([temporary])
        raise


def read_bytes(path: str) -> bytes:
    with FileSystems.open(path, compression_type=CompressionTypes.UNCOMPRESSED) as handle:
        return handle.read()


def list_files(pattern: str) -> list[str]:
    """Paths matching a glob, sorted; hidden partial files never match ``*.npz``."""
    result = FileSystems.match([pattern])[0]
    return sorted(m.path for m in result.metadata_list)
