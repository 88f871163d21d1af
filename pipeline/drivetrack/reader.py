"""Read one Waymo Open v2 segment's components with pyarrow, as typed NumPy records.

Layout: ``<root>/<component>/<segment_context_name>.parquet``. Paths go through Beam's
FileSystems, so a root on GCS or S3 works like a local folder.

Keys (``columns.KEYS``): each component holds one row per key, e.g. per (camera, timestamp) in
camera_image, per (object, timestamp) in the box files, per timestamp in vehicle_pose, per laser in
lidar_calibration. Key columns must hold integers (object ids: strings); their Parquet types are
checked when a file is opened. Among the rows a unit reads (its camera, the TOP laser at the frames
it asks for), a key on several rows is an InputError naming the file and the key, since either row
could be the true one; except that rows equal bit for bit in every column the reader uses are exact
copies, and only the first is kept. The lidar files are checked on their key columns before their
range images are streamed; rows whose key repeats are compared by digests of their range images.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from apache_beam.io.filesystems import FileSystems

from pipeline.core.errors import InputError
from pipeline.drivetrack import columns as C
from pipeline.drivetrack.records import (
    BoxLabels,
    CameraCalibration,
    CameraFrames,
    CameraMotion,
    LidarCalibration,
    LidarFrame,
)
from pipeline.io.files import open_binary

# Rows decoded at a time: a TOP lidar row is a few MB of range image, a camera row one JPEG.
BATCH_ROWS = 8
# Rows read at a time when only key columns are read.
KEY_BATCH_ROWS = 1 << 16


def list_segments(root: str) -> list[str]:
    """Segment names under ``<root>/camera_image/``, sorted."""
    folder = FileSystems.join(root, C.CAMERA_IMAGE)
    matches = FileSystems.match([FileSystems.join(folder, "*.parquet")])[0].metadata_list
    names = sorted(m.path.rsplit("/", 1)[-1][: -len(".parquet")] for m in matches)
    if not names:
        raise InputError(
            f"no segments: {folder} holds no .parquet files; --input must be a Waymo Open v2 "
            "split folder holding camera_image/, lidar/, ... component folders"
        )
    return names


def transforms_from_column(column: pa.ChunkedArray | pa.Array, what: str) -> np.ndarray:
    """Row-major 4x4 transforms stored as fixed_size_list<float>[16] or list<double>: [R, 4, 4]."""
    array = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    kind = array.type
    if not (pa.types.is_list(kind) or pa.types.is_large_list(kind) or pa.types.is_fixed_size_list(kind)):
        raise InputError(f"{what}: expected a list of 16 numbers, column type is {kind}")
    if not pa.types.is_floating(kind.value_type) and not pa.types.is_integer(kind.value_type):
        raise InputError(f"{what}: expected numbers in the transform, found {kind.value_type}")
    if array.null_count:
        raise InputError(f"{what}: {array.null_count} null transform(s)")
    lengths = pc.list_value_length(array).to_numpy(zero_copy_only=False)
    if len(lengths) and (lengths != 16).any():
        raise InputError(f"{what}: a transform has {lengths[lengths != 16][0]} values, expected 16")
    values = array.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
    return values.reshape(-1, 4, 4)


def _check_key_type(label: str, name: str, kind: pa.DataType) -> None:
    if name in C.STRING_KEYS:
        valid, expected = pa.types.is_string(kind) or pa.types.is_large_string(kind), "a string"
    else:
        valid, expected = pa.types.is_integer(kind), "an integer"
    if not valid:
        raise InputError(f"{label}: column {name} has type {kind}, expected {expected}")


def _bit_type(kind: pa.DataType) -> pa.DataType:
    """``kind`` with each float as an integer of its width: equal views hold equal bits (NaN too)."""
    if pa.types.is_floating(kind):
        return {16: pa.int16(), 32: pa.int32(), 64: pa.int64()}[kind.bit_width]
    if pa.types.is_fixed_size_list(kind):
        return pa.list_(_bit_type(kind.value_type), kind.list_size)
    if pa.types.is_list(kind):
        return pa.list_(_bit_type(kind.value_type))
    if pa.types.is_large_list(kind):
        return pa.large_list(_bit_type(kind.value_type))
    return kind


def _unique_rows(table: pa.Table, keys: tuple[str, ...], label: str) -> pa.Table:
    """``table`` less the rows that repeat an earlier row's key and equal it bit for bit in every
    column; InputError naming the key where a repeat differs (``_first_rows``)."""
    first = _first_rows(table, keys, label)
    return table if first.all() else table.filter(pa.array(first))


def _key_codes(table: pa.Table, keys: tuple[str, ...], label: str) -> list[np.ndarray]:
    """Each key column [R] as int64 codes (string keys by dictionary index); InputError for nulls."""
    codes = []
    for name in keys:
        if table.column(name).null_count:
            raise InputError(f"{label}: column {name} has {table.column(name).null_count} null value(s)")
        column = table.column(name).combine_chunks()
        column = pc.dictionary_encode(column).indices if name in C.STRING_KEYS else column
        codes.append(column.to_numpy().astype(np.int64, copy=False))
    return codes


def _first_of_key(table: pa.Table, keys: tuple[str, ...], label: str) -> np.ndarray:
    """[R] int64: per row, the first row holding its key."""
    count = table.num_rows
    codes = _key_codes(table, keys, label) if count else []
    if count < 2:
        return np.arange(count)
    order = np.lexsort(codes[::-1])  # stable: each run of equal keys starts with its first row
    ordered = np.stack(codes, 1)[order]
    repeat = np.zeros(count, bool)
    repeat[1:] = (ordered[1:] == ordered[:-1]).all(1)
    first = np.empty_like(order)
    first[order] = order[np.maximum.accumulate(np.where(repeat, 0, np.arange(count)))]
    return first


def _first_rows(table: pa.Table, keys: tuple[str, ...], label: str) -> np.ndarray:
    """[R] bool, True on the first row of each key; InputError naming the key where a later row
    differs from its first in any column. Keys are compared with NumPy; the other columns only on
    the rows whose key repeats."""
    first = _first_of_key(table, keys, label)
    rows = np.flatnonzero(first != np.arange(len(first)))
    for name in table.column_names if len(rows) else ():
        column = table.column(name).combine_chunks()
        column = column.view(_bit_type(column.type))
        ours, theirs = column.take(rows), column.take(first[rows])
        if not ours.equals(theirs):
            bad = next(r for i, r in enumerate(rows) if not ours.slice(i, 1).equals(theirs.slice(i, 1)))
            key = " at ".join(f"{C.KEY_WORDS[k]} {table.column(k)[int(bad)].as_py()!r}" for k in keys)
            count = int((first == first[bad]).sum())
            raise InputError(f"{label}: {key} appears in {count} rows with different values ({name} differs)")
    return first == np.arange(len(first))  # exact copies: keep the first


def _digest(cell: pa.Scalar) -> bytes | None:
    """blake2b of a list cell's values, bit for bit (None for a null cell)."""
    if not cell.is_valid:
        return None
    return hashlib.blake2b(cell.values.to_numpy(zero_copy_only=False).tobytes()).digest()


def _top_rows(batch: pa.RecordBatch, timestamps: pa.Array) -> pa.Array:
    """[R] True on the TOP laser's rows at one of ``timestamps``."""
    return pc.and_(
        pc.equal(batch.column(C.LASER_NAME), C.TOP_LASER),
        pc.is_in(batch.column(C.TIMESTAMP), value_set=timestamps),
    )


def _camera_rows(
    table: pa.Table | None, jpegs: list[bytes], camera: int, label: str
) -> tuple[pa.Table, list[bytes]]:
    """One camera's rows of ``camera_image`` (``table`` without its JPEG column, ``jpegs`` its
    JPEGs [R]), one per key: rows equal bit for bit, JPEG included, are copies (the first kept);
    InputError where a key's rows differ. The JPEGs are compared by digest, and only on the rows
    whose key repeats."""
    if table is None:
        return pa.table({C.TIMESTAMP: pa.array([], pa.int64())}), []
    rows = np.flatnonzero(table.column(C.CAMERA_NAME).to_numpy() == camera)
    mine = table.take(rows)
    first = _first_of_key(mine, C.KEYS[C.CAMERA_IMAGE], label)
    repeats = np.isin(first, first[first != np.arange(len(first))])
    digests = [
        hashlib.blake2b(jpegs[r] or b"").digest() if repeat else b""
        for r, repeat in zip(rows, repeats, strict=True)
    ]
    nulls = [jpegs[r] is None for r in rows]
    checked = mine.append_column(C.IMAGE_JPEG, pa.array(digests, pa.binary(), mask=np.array(nulls, bool)))
    kept = _first_rows(checked, C.KEYS[C.CAMERA_IMAGE], label)
    return mine.filter(pa.array(kept)), [jpegs[r] for r in rows[kept]]


def _optional_numbers(table: pa.Table, name: str, what: str) -> np.ndarray:
    """A numeric column as float64, NaN where null; InputError for a NaN or infinite value."""
    column = table.column(name)
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        raise InputError(f"{what}: column {name} has type {column.type}, expected numbers")
    values = column.to_numpy(zero_copy_only=False).astype(np.float64)
    valid = column.is_valid().to_numpy(zero_copy_only=False)
    if not np.isfinite(values[valid]).all():
        raise InputError(f"{what}: column {name} holds NaN or infinity")
    return np.where(valid, values, np.nan)


def _numbers(table: pa.Table, name: str, what: str, dtype=np.float64) -> np.ndarray:
    column = table.column(name)
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        raise InputError(f"{what}: column {name} has type {column.type}, expected numbers")
    if column.null_count:
        raise InputError(f"{what}: column {name} has {column.null_count} null value(s)")
    return column.to_numpy().astype(dtype)


class SegmentReader:
    """Typed access to one segment's components; every error names the file and the cause."""

    def __init__(self, root: str, segment: str):
        self.root = root
        self.segment = segment

    def _path(self, component: str) -> str:
        return FileSystems.join(self.root, component, f"{self.segment}.parquet")

    def check_components(self) -> None:
        """Raise InputError naming the first of the segment's component files that is absent."""
        for component in C.COMPONENTS:
            if not FileSystems.exists(self._path(component)):
                raise InputError(f"missing component file {component}/{self.segment}.parquet")

    def batches(
        self,
        component: str,
        columns: list[str],
        batch_rows: int = BATCH_ROWS,
        optional: tuple[str, ...] = (),
    ) -> Iterator[pa.RecordBatch]:
        """Columns of one component file, ``batch_rows`` rows at a time (a segment's lidar files
        decode to several GiB; only the rows a unit keeps are ever held), and those of ``optional``
        the file has; clear errors for bad files, key columns of the wrong type among them (from
        the schema, before any row is read)."""
        path = self._path(component)
        label = f"{component}/{self.segment}.parquet"
        if not FileSystems.exists(path):
            raise InputError(f"missing component file {label}")
        try:
            with open_binary(path) as handle:
                parquet = pq.ParquetFile(handle, pre_buffer=False)
                present = set(parquet.schema_arrow.names)
                missing = [name for name in columns if name not in present]
                if missing:
                    raise InputError(f"{label}: missing column(s) {missing}")
                for name in columns:
                    if name in C.KEY_WORDS:
                        _check_key_type(label, name, parquet.schema_arrow.field(name).type)
                columns = columns + [name for name in optional if name in present]
                yield from parquet.iter_batches(batch_size=batch_rows, columns=columns)
        except InputError:
            raise
        except (pa.ArrowException, OSError, ValueError) as error:
            raise InputError(f"{label}: unreadable Parquet ({error})") from error

    def read(
        self, component: str, columns: list[str], filters=None, optional: tuple[str, ...] = ()
    ) -> pa.Table:
        """The rows of one component file that pass ``filters`` (a pyarrow expression), as a table,
        one row per key (``columns`` must hold the component's key columns; see the module's doc),
        with the columns of ``optional`` that the file has."""
        return _unique_rows(
            self._rows(component, columns, filters, optional),
            C.KEYS[component],
            f"{component}/{self.segment}.parquet",
        )

    def _rows(self, component: str, columns: list[str], filters, optional: tuple[str, ...]) -> pa.Table:
        """``read``'s table before repeated keys are checked."""
        batches = self.batches(component, columns, optional=optional)
        parts = [pa.Table.from_batches([batch]) for batch in batches]
        if filters is not None:
            parts = [part.filter(filters) for part in parts]
        if not parts:
            return pa.table({name: pa.array([]) for name in columns})
        return pa.concat_tables(parts).combine_chunks()

    def camera_calibration(self, camera: int) -> CameraCalibration:
        names = [C.CAMERA_NAME, *C.CAM_INTRINSICS, *C.CAM_DISTORTION, C.CAM_EXTRINSIC]
        names += [C.CAM_WIDTH, C.CAM_HEIGHT]
        direction = C.CAM_ROLLING_SHUTTER_DIRECTION
        table = self.read(
            C.CAMERA_CALIBRATION, names, pc.field(C.CAMERA_NAME) == camera, optional=(direction,)
        )
        what = f"camera_calibration/{self.segment} camera {camera}"
        if table.num_rows != 1:
            raise InputError(f"{what}: expected 1 row, found {table.num_rows}")
        intrinsics = np.array([_numbers(table, n, what)[0] for n in C.CAM_INTRINSICS])
        distortion = np.array([_numbers(table, n, what)[0] for n in C.CAM_DISTORTION])
        extrinsic = transforms_from_column(table.column(C.CAM_EXTRINSIC), what)[0]
        width = int(_numbers(table, C.CAM_WIDTH, what, np.int64)[0])
        height = int(_numbers(table, C.CAM_HEIGHT, what, np.int64)[0])
        if not np.all(np.isfinite(intrinsics)) or (intrinsics[:2] <= 0).any():
            raise InputError(f"{what}: invalid intrinsics {intrinsics.tolist()}")
        if not np.all(np.isfinite(distortion)):
            raise InputError(f"{what}: invalid distortion {distortion.tolist()}")
        readout = _optional_numbers(table, direction, what)[0] if direction in table.column_names else 0
        readout = 0 if np.isnan(readout) else int(readout)
        return CameraCalibration(intrinsics, distortion, extrinsic, width, height, readout)

    def lidar_calibration(self) -> LidarCalibration:
        names = [C.LASER_NAME, C.LIDAR_EXTRINSIC, C.BEAM_INCLINATION_VALUES]
        names += [C.BEAM_INCLINATION_MIN, C.BEAM_INCLINATION_MAX]
        table = self.read(C.LIDAR_CALIBRATION, names, pc.field(C.LASER_NAME) == C.TOP_LASER)
        what = f"lidar_calibration/{self.segment} TOP"
        if table.num_rows != 1:
            raise InputError(f"{what}: expected 1 row, found {table.num_rows}")
        extrinsic = transforms_from_column(table.column(C.LIDAR_EXTRINSIC), what)[0]
        values = table.column(C.BEAM_INCLINATION_VALUES)[0]
        inclinations = None if not values.is_valid else np.asarray(values.values, np.float64)
        return LidarCalibration(
            extrinsic,
            inclinations,
            float(_numbers(table, C.BEAM_INCLINATION_MIN, what)[0]),
            float(_numbers(table, C.BEAM_INCLINATION_MAX, what)[0]),
        )

    def vehicle_poses(self) -> dict[int, np.ndarray]:
        """world_from_vehicle [4, 4] per frame timestamp."""
        table = self.read(C.VEHICLE_POSE, [C.TIMESTAMP, C.WORLD_FROM_VEHICLE])
        what = f"vehicle_pose/{self.segment}"
        poses = transforms_from_column(table.column(C.WORLD_FROM_VEHICLE), what)
        stamps = _numbers(table, C.TIMESTAMP, what, np.int64)
        return dict(zip(stamps.tolist(), poses, strict=True))

    def camera_frames(self, camera: int) -> CameraFrames:
        (frames,) = self.cameras_frames([camera])
        if isinstance(frames, InputError):
            raise frames
        return frames

    def cameras_frames(self, cameras: list[int]) -> list[CameraFrames | InputError]:
        """Each camera's frames, the ``camera_image`` file read once for all of them; per camera
        the InputError of its own bad rows (a bad file fails them all: raised).

        The file is streamed ``BATCH_ROWS`` rows at a time: of each batch, the wanted cameras'
        JPEGs become Python bytes at once and their other columns (a few numbers a row) are kept,
        so beside the unit's JPEGs only the row group pyarrow decodes is ever held."""
        names = [C.TIMESTAMP, C.CAMERA_NAME, C.IMAGE_JPEG, C.IMAGE_POSE]
        label = f"{C.CAMERA_IMAGE}/{self.segment}.parquet"
        parts: list[pa.RecordBatch] = []
        jpegs: list[bytes] = []  # of the rows of ``parts``, in order
        for batch in self.batches(C.CAMERA_IMAGE, names, optional=C.ROLLING_SHUTTER):
            column = batch.column(C.CAMERA_NAME)
            kept = batch.filter(pc.is_in(column, value_set=pa.array(cameras, column.type)))
            jpegs.extend(kept.column(C.IMAGE_JPEG).to_pylist())
            parts.append(kept.drop_columns([C.IMAGE_JPEG]))
        table = pa.Table.from_batches(parts) if parts else None
        found: list[CameraFrames | InputError] = []
        for camera in cameras:
            try:
                found.append(self._camera_frames(_camera_rows(table, jpegs, camera, label), camera))
            except InputError as error:
                found.append(error)
        return found

    def _camera_frames(self, rows: tuple[pa.Table, list[bytes]], camera: int) -> CameraFrames:
        """One camera's ``camera_image`` rows (keys unique; JPEGs apart) as its frames, in time order."""
        table, jpegs = rows
        what = f"camera_image/{self.segment} camera {camera}"
        if table.num_rows == 0:
            raise InputError(f"{what}: no frames")
        stamps = _numbers(table, C.TIMESTAMP, what, np.int64)
        order = np.argsort(stamps, kind="stable")
        poses = transforms_from_column(table.column(C.IMAGE_POSE), what)
        motion = None
        if set(C.ROLLING_SHUTTER) <= set(table.column_names):
            values = {name: _optional_numbers(table, name, what)[order] for name in C.ROLLING_SHUTTER}
            shutter, trigger, readout_done = (values[name] for name in C.IMAGE_SHUTTER)
            motion = CameraMotion(
                values[C.IMAGE_POSE_TIMESTAMP],
                shutter,
                trigger,
                readout_done,
                np.stack([values[name] for name in C.IMAGE_LINEAR_VELOCITY], 1),
                np.stack([values[name] for name in C.IMAGE_ANGULAR_VELOCITY], 1),
            )
        return CameraFrames(stamps[order], [jpegs[i] for i in order], poses[order], motion)

    def box_labels(self) -> BoxLabels:
        what = f"lidar_box/{self.segment}"
        boxes = self.read(C.LIDAR_BOX, [C.TIMESTAMP, C.OBJECT_ID, C.BOX_TYPE, *C.BOX_FIELDS])
        synced = self.read(
            C.LIDAR_CAMERA_SYNCED_BOX,
            [C.TIMESTAMP, C.OBJECT_ID, C.MOST_VISIBLE_CAMERA, *C.SYNCED_BOX_FIELDS],
        )
        for component, table in ((C.LIDAR_BOX, boxes), (C.LIDAR_CAMERA_SYNCED_BOX, synced)):
            if table.num_rows == 0:
                raise InputError(
                    f"{component}/{self.segment}.parquet: no 3D boxes (0 rows); DriveTrack needs a "
                    "labelled segment (training or validation split)"
                )
        synced_what = f"lidar_camera_synced_box/{self.segment}"
        synced_rows = {
            key: row
            for row, key in enumerate(
                zip(
                    _numbers(synced, C.TIMESTAMP, synced_what, np.int64).tolist(),
                    synced.column(C.OBJECT_ID).to_pylist(),
                    strict=True,
                )
            )
        }
        synced_values = np.stack([_numbers(synced, n, synced_what) for n in C.SYNCED_BOX_FIELDS], 1)
        visible_camera = _numbers(synced, C.MOST_VISIBLE_CAMERA, synced_what, np.int64)
        box_values = np.stack([_numbers(boxes, n, what) for n in C.BOX_FIELDS], axis=1)
        stamps = _numbers(boxes, C.TIMESTAMP, what, np.int64)
        ids = boxes.column(C.OBJECT_ID).to_pylist()
        types = _numbers(boxes, C.BOX_TYPE, what, np.int64)
        pairs = [(i, synced_rows.get((stamps[i], ids[i]))) for i in range(len(ids))]
        pairs = [(i, j) for i, j in pairs if j is not None]
        pairs.sort(key=lambda p: (ids[p[0]], stamps[p[0]]))
        rows = np.array([i for i, _ in pairs], dtype=np.int64)
        srows = np.array([j for _, j in pairs], dtype=np.int64)
        return BoxLabels(
            object_ids=np.array([ids[i] for i in rows], dtype=object),
            timestamps=stamps[rows],
            types=types[rows],
            lidar_boxes=box_values[rows].reshape(-1, 7),
            synced_boxes=synced_values[srows].reshape(-1, 7),
            most_visible_camera=visible_camera[srows],
        )

    def top_lidar_frames(self, timestamps: list[int]) -> Iterator[LidarFrame]:
        """TOP lidar first-return range images with per-pixel poses and camera projections, in the
        order of ``timestamps``. The three files are streamed side by side and each frame is handed
        on as soon as its three parts are read, so memory holds a few frames, not the segment
        (rows out of time order are buffered until asked for)."""
        parts = {
            name: self._top_images(name, values, shape, channels, timestamps)
            for name, values, shape, channels in (
                (C.LIDAR, C.LIDAR_RANGE_VALUES, C.LIDAR_RANGE_SHAPE, 4),
                (C.LIDAR_POSE, C.LIDAR_POSE_VALUES, C.LIDAR_POSE_SHAPE, 6),
                (C.LIDAR_CAMERA_PROJECTION, C.PROJECTION_VALUES, C.PROJECTION_SHAPE, 6),
            )
        }
        pending: dict[str, dict[int, np.ndarray]] = {name: {} for name in parts}
        for timestamp in timestamps:
            arrays = []
            for name, stream in parts.items():
                buffer = pending[name]
                while timestamp not in buffer:
                    row = next(stream, None)
                    if row is None:
                        what = f"{name}/{self.segment} TOP frame {timestamp}"
                        raise InputError(f"{what}: no row for this frame")
                    buffer[row[0]] = row[1]
                arrays.append(buffer.pop(timestamp))
            yield LidarFrame(timestamp, arrays[0][..., 0].copy(), arrays[1], arrays[2])

    def _top_images(
        self, component: str, values: str, shape: str, channels: int, timestamps: list[int]
    ) -> Iterator[tuple[int, np.ndarray]]:
        """(timestamp, range image [H, W, channels]) of each TOP row at one of ``timestamps``."""
        wanted = pa.array(sorted(set(timestamps)), pa.int64())
        self._check_top_repeats(component, [values, shape], wanted)
        seen: set[int] = set()
        for batch in self.batches(component, [C.TIMESTAMP, C.LASER_NAME, values, shape]):
            # Row indices, not batch.filter: filtering copies every kept range image (slow for lists).
            rows = np.flatnonzero(_top_rows(batch, wanted).to_numpy(zero_copy_only=False))
            stamps = batch.column(C.TIMESTAMP).to_numpy()
            for row in rows.tolist():
                timestamp = int(stamps[row])
                if timestamp in seen:
                    continue  # an exact copy of a row handed on already (checked above)
                seen.add(timestamp)
                what = f"{component}/{self.segment} TOP frame {timestamp}"
                image = _range_image(batch, row, values, shape, channels, what)
                yield timestamp, image.copy()  # a copy: the batch's buffers are let go

    def _check_top_repeats(self, component: str, columns: list[str], wanted: pa.Array) -> None:
        """InputError if a TOP row at one of ``wanted`` repeats its timestamp with other ``columns``
        values. Reads the key columns only; where a key repeats, also that key's rows, compared by
        digests of their cells (a range image is a few MB)."""
        keys = [C.TIMESTAMP, C.LASER_NAME]
        stamps = [
            batch.filter(_top_rows(batch, wanted)).column(C.TIMESTAMP).to_numpy()
            for batch in self.batches(component, keys, KEY_BATCH_ROWS)
        ]
        unique, counts = np.unique(np.concatenate([np.zeros(0, np.int64), *stamps]), return_counts=True)
        if (counts < 2).all():
            return
        repeated = pa.array(unique[counts > 1], pa.int64())
        parts = []
        for batch in self.batches(component, keys + columns):
            rows = batch.filter(_top_rows(batch, repeated))
            digests = {
                name: pa.array([_digest(c) for c in rows.column(name)], pa.binary()) for name in columns
            }
            parts.append(pa.table({**{k: rows.column(k) for k in keys}, **digests}))
        _unique_rows(pa.concat_tables(parts), C.KEYS[component], f"{component}/{self.segment}.parquet")


def _range_image(
    table: pa.Table | pa.RecordBatch, row: int, values_name: str, shape_name: str, channels: int, what: str
) -> np.ndarray:
    shape_cell = table.column(shape_name)[row]
    values_cell = table.column(values_name)[row]
    if not shape_cell.is_valid or not values_cell.is_valid:
        raise InputError(f"{what}: empty range image")
    shape = [int(s) for s in shape_cell.values.to_numpy(zero_copy_only=False)]
    values = values_cell.values.to_numpy(zero_copy_only=False)
    if len(shape) != 3 or shape[2] != channels or int(np.prod(shape)) != values.size:
        raise InputError(
            f"{what}: range image shape {shape} does not hold {values.size} values with {channels} channels"
        )
    if values.size == 0:
        raise InputError(f"{what}: empty range image")
    return values.reshape(shape)
