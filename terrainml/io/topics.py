"""Default ROS 2 topic names and message types (design §5). A YAML topic map overrides them."""

from __future__ import annotations

IMU = "/imu"
CAMERA_ODOM = "/camera/odom/sample"
WHEEL_JOINTS = "/wheels/joint_states"
MOTOR_CURRENT = "/wheels/motor_current"
CMD_VEL = "/cmd_vel"
TERRAIN_LABEL = "/terrain/label"
# simulator truth
SIM_GROUND_TRUTH = "/sim/ground_truth"
SIM_WHEEL_SLIP = "/sim/wheel_slip"
SIM_WHEEL_STATE = "/sim/wheel_state"

MESSAGE_TYPES = {
    IMU: "sensor_msgs/msg/Imu",
    CAMERA_ODOM: "nav_msgs/msg/Odometry",
    WHEEL_JOINTS: "sensor_msgs/msg/JointState",
    MOTOR_CURRENT: "sensor_msgs/msg/JointState",
    CMD_VEL: "geometry_msgs/msg/Twist",
    TERRAIN_LABEL: "std_msgs/msg/UInt8",
    SIM_GROUND_TRUTH: "nav_msgs/msg/Odometry",
    SIM_WHEEL_SLIP: "sensor_msgs/msg/JointState",
    SIM_WHEEL_STATE: "sensor_msgs/msg/JointState",
}

# Codes of /sim/wheel_state (position field); order of terrainml.schema.WHEEL_STATES.
WHEEL_STATE_CODES = {"idle": 0, "steady": 1, "traction": 2, "braking": 3}
