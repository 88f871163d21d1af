"""Waymo Open Dataset v2 component and column names, spelled exactly as in the files."""

SEGMENT = "key.segment_context_name"
TIMESTAMP = "key.frame_timestamp_micros"
CAMERA_NAME = "key.camera_name"
LASER_NAME = "key.laser_name"
OBJECT_ID = "key.laser_object_id"

CAMERA_IMAGE = "camera_image"
IMAGE_JPEG = "[CameraImageComponent].image"
IMAGE_POSE = "[CameraImageComponent].pose.transform"
# The rolling shutter's inputs (optional: a file without them is read as a global shutter).
IMAGE_POSE_TIMESTAMP = "[CameraImageComponent].pose_timestamp"
IMAGE_LINEAR_VELOCITY = tuple(f"[CameraImageComponent].velocity.linear_velocity.{k}" for k in "xyz")
IMAGE_ANGULAR_VELOCITY = tuple(f"[CameraImageComponent].velocity.angular_velocity.{k}" for k in "xyz")
IMAGE_SHUTTER = tuple(
    f"[CameraImageComponent].rolling_shutter_params.{k}"
    for k in ("shutter", "camera_trigger_time", "camera_readout_done_time")
)
ROLLING_SHUTTER = (IMAGE_POSE_TIMESTAMP, *IMAGE_LINEAR_VELOCITY, *IMAGE_ANGULAR_VELOCITY, *IMAGE_SHUTTER)

CAMERA_CALIBRATION = "camera_calibration"
_CC = "[CameraCalibrationComponent]"
CAM_INTRINSICS = tuple(f"{_CC}.intrinsic.{k}" for k in ("f_u", "f_v", "c_u", "c_v"))
CAM_DISTORTION = tuple(f"{_CC}.intrinsic.{k}" for k in ("k1", "k2", "p1", "p2", "k3"))
CAM_EXTRINSIC = f"{_CC}.extrinsic.transform"
CAM_WIDTH = f"{_CC}.width"
CAM_HEIGHT = f"{_CC}.height"
CAM_ROLLING_SHUTTER_DIRECTION = f"{_CC}.rolling_shutter_direction"  # optional

LIDAR = "lidar"
LIDAR_RANGE_VALUES = "[LiDARComponent].range_image_return1.values"
LIDAR_RANGE_SHAPE = "[LiDARComponent].range_image_return1.shape"

LIDAR_CALIBRATION = "lidar_calibration"
_LC = "[LiDARCalibrationComponent]"
LIDAR_EXTRINSIC = f"{_LC}.extrinsic.transform"
BEAM_INCLINATION_VALUES = f"{_LC}.beam_inclination.values"
BEAM_INCLINATION_MIN = f"{_LC}.beam_inclination.min"
BEAM_INCLINATION_MAX = f"{_LC}.beam_inclination.max"

LIDAR_POSE = "lidar_pose"
LIDAR_POSE_VALUES = "[LiDARPoseComponent].range_image_return1.values"
LIDAR_POSE_SHAPE = "[LiDARPoseComponent].range_image_return1.shape"

LIDAR_CAMERA_PROJECTION = "lidar_camera_projection"
PROJECTION_VALUES = "[LiDARCameraProjectionComponent].range_image_return1.values"
PROJECTION_SHAPE = "[LiDARCameraProjectionComponent].range_image_return1.shape"

LIDAR_BOX = "lidar_box"
_LB = "[LiDARBoxComponent]"
BOX_FIELDS = tuple(
    f"{_LB}.box.{k}" for k in ("center.x", "center.y", "center.z", "size.x", "size.y", "size.z", "heading")
)
BOX_TYPE = f"{_LB}.type"

LIDAR_CAMERA_SYNCED_BOX = "lidar_camera_synced_box"
_SB = "[LiDARCameraSyncedBoxComponent]"
SYNCED_BOX_FIELDS = tuple(
    f"{_SB}.camera_synced_box.{k}"
    for k in ("center.x", "center.y", "center.z", "size.x", "size.y", "size.z", "heading")
)
MOST_VISIBLE_CAMERA = f"{_SB}.most_visible_camera_name"

VEHICLE_POSE = "vehicle_pose"
WORLD_FROM_VEHICLE = "[VehiclePoseComponent].world_from_vehicle.transform"

COMPONENTS = (
    CAMERA_IMAGE,
    CAMERA_CALIBRATION,
    LIDAR,
    LIDAR_CALIBRATION,
    LIDAR_POSE,
    LIDAR_CAMERA_PROJECTION,
    LIDAR_BOX,
    LIDAR_CAMERA_SYNCED_BOX,
    VEHICLE_POSE,
)

TOP_LASER = 1

# Each component's key: the columns that name one row (the segment aside, as a file holds one segment).
KEYS = {
    CAMERA_IMAGE: (CAMERA_NAME, TIMESTAMP),
    CAMERA_CALIBRATION: (CAMERA_NAME,),
    LIDAR: (LASER_NAME, TIMESTAMP),
    LIDAR_CALIBRATION: (LASER_NAME,),
    LIDAR_POSE: (LASER_NAME, TIMESTAMP),
    LIDAR_CAMERA_PROJECTION: (LASER_NAME, TIMESTAMP),
    LIDAR_BOX: (OBJECT_ID, TIMESTAMP),
    LIDAR_CAMERA_SYNCED_BOX: (OBJECT_ID, TIMESTAMP),
    VEHICLE_POSE: (TIMESTAMP,),
}
# A key column's word in messages; object ids are strings, the other key columns integers.
KEY_WORDS = {OBJECT_ID: "object", CAMERA_NAME: "camera", LASER_NAME: "laser", TIMESTAMP: "timestamp"}
STRING_KEYS = (OBJECT_ID,)
