"""Foreground masks decoded once per process: a bounded cache of decoded masks keyed by the file's
bytes.

Every (sequence, camera) unit reads every camera's mask at every frame (the multi-view mask
statistic), so a worker that runs several units of a sequence would decode the same PNGs once
per unit: 27 x 150 of them for a Panoptic Studio sequence, about a third of a unit's time. The
cache maps a mask file's exact bytes and the expected size to the decoded mask, bit-packed
(H W / 8 bytes: 28.8 kB at 640x360, a 27-camera 150-frame sequence 117 MB), least recently used
evicted beyond MAX_BYTES. Keyed by content, a hit returns exactly what decoding
those bytes returns: outputs do not depend on which units a worker ran before, in what order,
or on retries. Files are still read once per opened sequence (``reader.SequenceFiles``: a path or
timestamp would not prove the bytes unchanged from one group of units to the next). Thread-safe:
a runner may run units on several threads of one process.
"""

from __future__ import annotations

import collections
import threading

import numpy as np

from pipeline.core.images import decode_image

MAX_BYTES = 256 << 20  # packed masks and their keys: two 27-camera, 150-frame 640x360 sequences


class MaskCache:
    """Decoded masks [H, W] bool by (file bytes, width, height), bit-packed, at most ``max_bytes``."""

    def __init__(self, max_bytes: int = MAX_BYTES):
        self.max_bytes = max_bytes
        self.bytes = 0
        self._packed: collections.OrderedDict[tuple[bytes, int, int], np.ndarray] = collections.OrderedDict()
        self._lock = threading.Lock()

    def packed(self, data: bytes, width: int, height: int, what: str) -> np.ndarray:
        """The mask (non-zero pixels) of the PNG or JPEG ``data``, bit-packed (``np.packbits`` of
        the [H, W] bools, row-major; ``unpack_mask`` gives them back); InputError naming ``what``
        when it is not a ``width`` x ``height`` image."""
        key = (data, width, height)
        with self._lock:
            packed = self._packed.get(key)
            if packed is not None:
                self._packed.move_to_end(key)
        if packed is None:
            packed = np.packbits(decode_image(data, width, height, what, noun="mask") > 0)
            self._insert(key, packed)
        return packed

    def _insert(self, key: tuple[bytes, int, int], packed: np.ndarray) -> None:
        size = len(key[0]) + packed.nbytes
        with self._lock:
            if key in self._packed or size > self.max_bytes:
                return
            self._packed[key] = packed
            self.bytes += size
            while self.bytes > self.max_bytes:
                old_key, old = self._packed.popitem(last=False)
                self.bytes -= len(old_key[0]) + old.nbytes


def unpack_mask(packed: np.ndarray, width: int, height: int) -> np.ndarray:
    """A packed mask (``MaskCache.packed``) as [H, W] bool."""
    return np.unpackbits(packed, count=width * height).view(np.bool_).reshape(height, width)


MASKS = MaskCache()
