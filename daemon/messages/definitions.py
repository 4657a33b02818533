# The ROS 2 message definitions arbiterd speaks, as .msg text (fields and defaults per ROS 2).
from __future__ import annotations

# name (pkg/msg/Type) => .msg text; nested types in the same package are written without the
# package, as in the ROS 2 interface files, and `MSG: pkg/Type` sections are built from these.
MSG_TEXT: dict[str, str] = {
    "builtin_interfaces/msg/Time": (
        "# Time on the ROS time axis: seconds and nanoseconds since the epoch.\n"
        "int32 sec\n"
        "uint32 nanosec\n"),
    "builtin_interfaces/msg/Duration": (
        "# A signed span of time.\n"
        "int32 sec\n"
        "uint32 nanosec\n"),
    "std_msgs/msg/Header": (
        "# Stamp and coordinate frame of higher-level data.\n"
        "builtin_interfaces/Time stamp\n"
        "string frame_id\n"),
    "std_msgs/msg/String": "string data\n",
    "std_msgs/msg/Bool": "bool data\n",
    "std_msgs/msg/Empty": "",
    "std_msgs/msg/Int32": "int32 data\n",
    "std_msgs/msg/Float64": "float64 data\n",
    "std_msgs/msg/MultiArrayDimension": (
        "string label\n"
        "uint32 size\n"
        "uint32 stride\n"),
    "std_msgs/msg/MultiArrayLayout": (
        "MultiArrayDimension[] dim\n"
        "uint32 data_offset\n"),
    "std_msgs/msg/UInt8MultiArray": (
        "MultiArrayLayout layout\n"
        "uint8[] data\n"),
    "geometry_msgs/msg/Vector3": (
        "# A vector in free space.\n"
        "float64 x\n"
        "float64 y\n"
        "float64 z\n"),
    "geometry_msgs/msg/Point": (
        "float64 x\n"
        "float64 y\n"
        "float64 z\n"),
    "geometry_msgs/msg/Quaternion": (
        "# An orientation as a quaternion (identity by default).\n"
        "float64 x 0\n"
        "float64 y 0\n"
        "float64 z 0\n"
        "float64 w 1\n"),
    "geometry_msgs/msg/Pose": (
        "Point position\n"
        "Quaternion orientation\n"),
    "geometry_msgs/msg/PoseWithCovariance": (
        "Pose pose\n"
        "# Row-major 6x6 covariance of (x, y, z, roll, pitch, yaw).\n"
        "float64[36] covariance\n"),
    "geometry_msgs/msg/Twist": (
        "# Velocity in free space: linear and angular parts.\n"
        "Vector3 linear\n"
        "Vector3 angular\n"),
    "geometry_msgs/msg/TwistStamped": (
        "std_msgs/Header header\n"
        "Twist twist\n"),
    "geometry_msgs/msg/TwistWithCovariance": (
        "Twist twist\n"
        "float64[36] covariance\n"),
    "geometry_msgs/msg/Transform": (
        "Vector3 translation\n"
        "Quaternion rotation\n"),
    "geometry_msgs/msg/TransformStamped": (
        "std_msgs/Header header\n"
        "string child_frame_id\n"
        "Transform transform\n"),
    "nav_msgs/msg/Odometry": (
        "# Pose in header.frame_id, twist in child_frame_id.\n"
        "std_msgs/Header header\n"
        "string child_frame_id\n"
        "geometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist\n"),
    "geometry_msgs/msg/PoseStamped": (
        "std_msgs/Header header\n"
        "Pose pose\n"),
    "geometry_msgs/msg/PoseWithCovarianceStamped": (
        "std_msgs/Header header\n"
        "PoseWithCovariance pose\n"),
    "geometry_msgs/msg/PointStamped": (
        "std_msgs/Header header\n"
        "Point point\n"),
    "nav_msgs/msg/MapMetaData": (
        "# The grid's size and where its cell (0, 0) lies.\n"
        "builtin_interfaces/Time map_load_time\n"
        "float32 resolution\n"
        "uint32 width\n"
        "uint32 height\n"
        "geometry_msgs/Pose origin\n"),
    "nav_msgs/msg/OccupancyGrid": (
        "# A 2D grid map: row-major from the origin, -1 unknown, 0..100 occupied.\n"
        "std_msgs/Header header\n"
        "MapMetaData info\n"
        "int8[] data\n"),
    "nav_msgs/msg/Path": (
        "std_msgs/Header header\n"
        "geometry_msgs/PoseStamped[] poses\n"),
    "sensor_msgs/msg/LaserScan": (
        "# One revolution of a planar laser range finder.\n"
        "std_msgs/Header header\n"
        "float32 angle_min\n"
        "float32 angle_max\n"
        "float32 angle_increment\n"
        "float32 time_increment\n"
        "float32 scan_time\n"
        "float32 range_min\n"
        "float32 range_max\n"
        "float32[] ranges\n"
        "float32[] intensities\n"),
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\n"
        "string[] name\n"
        "float64[] position\n"
        "float64[] velocity\n"
        "float64[] effort\n"),
    "sensor_msgs/msg/BatteryState": (
        "# A battery's state (sensor_msgs/msg/BatteryState, ROS 2).\n"
        "uint8 POWER_SUPPLY_STATUS_UNKNOWN=0\n"
        "uint8 POWER_SUPPLY_STATUS_CHARGING=1\n"
        "uint8 POWER_SUPPLY_STATUS_DISCHARGING=2\n"
        "uint8 POWER_SUPPLY_STATUS_NOT_CHARGING=3\n"
        "uint8 POWER_SUPPLY_STATUS_FULL=4\n"
        "uint8 POWER_SUPPLY_HEALTH_UNKNOWN=0\n"
        "uint8 POWER_SUPPLY_HEALTH_GOOD=1\n"
        "uint8 POWER_SUPPLY_HEALTH_OVERHEAT=2\n"
        "uint8 POWER_SUPPLY_HEALTH_DEAD=3\n"
        "uint8 POWER_SUPPLY_HEALTH_OVERVOLTAGE=4\n"
        "uint8 POWER_SUPPLY_HEALTH_UNSPEC_FAILURE=5\n"
        "uint8 POWER_SUPPLY_HEALTH_COLD=6\n"
        "uint8 POWER_SUPPLY_HEALTH_WATCHDOG_TIMER_EXPIRE=7\n"
        "uint8 POWER_SUPPLY_HEALTH_SAFETY_TIMER_EXPIRE=8\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_UNKNOWN=0\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_NIMH=1\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_LION=2\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_LIPO=3\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_LIFE=4\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_NICD=5\n"
        "uint8 POWER_SUPPLY_TECHNOLOGY_LIMN=6\n"
        "std_msgs/Header header\n"
        "float32 voltage\n"
        "float32 temperature\n"
        "float32 current\n"
        "float32 charge\n"
        "float32 capacity\n"
        "float32 design_capacity\n"
        "float32 percentage\n"
        "uint8 power_supply_status\n"
        "uint8 power_supply_health\n"
        "uint8 power_supply_technology\n"
        "bool present\n"
        "float32[] cell_voltage\n"
        "float32[] cell_temperature\n"
        "string location\n"
        "string serial_number\n"),
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "sensor_msgs/msg/CompressedImage": (
        "# A compressed image: format is jpeg or png.\n"
        "std_msgs/Header header\n"
        "string format\n"
        "uint8[] data\n"),
    "sensor_msgs/msg/Image": (
        "# An uncompressed image, row by row from the top left.\n"
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string encoding\n"
        "uint8 is_bigendian\n"
        "uint32 step\n"
        "uint8[] data\n"),
    "sensor_msgs/msg/RegionOfInterest": (
        "uint32 x_offset\n"
        "uint32 y_offset\n"
        "uint32 height\n"
        "uint32 width\n"
        "bool do_rectify\n"),
    "sensor_msgs/msg/CameraInfo": (
        "# A camera's calibration: the pinhole model of its images.\n"
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string distortion_model\n"
        "float64[] d\n"
        "float64[9] k\n"
        "float64[9] r\n"
        "float64[12] p\n"
        "uint32 binning_x\n"
        "uint32 binning_y\n"
        "RegionOfInterest roi\n"),
    "rcl_interfaces/msg/Log": (
        "# A log line, as published on /rosout.\n"
        "byte DEBUG=10\n"
        "byte INFO=20\n"
        "byte WARN=30\n"
        "byte ERROR=40\n"
        "byte FATAL=50\n"
        "builtin_interfaces/Time stamp\n"
        "uint8 level\n"
        "string name\n"
        "string msg\n"
        "string file\n"
        "string function\n"
        "uint32 line\n"),
    "diagnostic_msgs/msg/KeyValue": (
        "string key\n"
        "string value\n"),
    "diagnostic_msgs/msg/DiagnosticStatus": (
        "# The state of one part of the system.\n"
        "byte OK=0\n"
        "byte WARN=1\n"
        "byte ERROR=2\n"
        "byte STALE=3\n"
        "byte level\n"
        "string name\n"
        "string message\n"
        "string hardware_id\n"
        "KeyValue[] values\n"),
    "diagnostic_msgs/msg/DiagnosticArray": (
        "std_msgs/Header header\n"
        "DiagnosticStatus[] status\n"),
    "arbiterd_msgs/msg/Command": (
        "# A motion command arbiterd received, as its flight recorder logs it.\n"
        "builtin_interfaces/Time stamp\n"
        "# who sent it: http, ws:<client>, autonomy, ...\n"
        "string source\n"
        "# cmd_vel, estop or estop_release\n"
        "string kind\n"
        "# the command's id when it was stamped, else empty\n"
        "string id\n"
        "geometry_msgs/Twist twist\n"
        "bool accepted\n"
        "# why it was not applied (empty when accepted)\n"
        "string error\n"),
}

# names of the types the daemon itself publishes or accepts
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
STRING = "std_msgs/msg/String"
BOOL = "std_msgs/msg/Bool"
ODOMETRY = "nav_msgs/msg/Odometry"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
JOINT_STATE = "sensor_msgs/msg/JointState"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
LOG = "rcl_interfaces/msg/Log"
COMMAND = "arbiterd_msgs/msg/Command"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
FLOAT64 = "std_msgs/msg/Float64"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
POINT_STAMPED = "geometry_msgs/msg/PointStamped"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
PATH = "nav_msgs/msg/Path"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
