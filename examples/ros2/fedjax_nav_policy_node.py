#!/usr/bin/env python3
"""A ROS 2 node that drives a TurtleBot3-like robot with a policy exported by `fedjax-nav export`.

    python3 fedjax_nav_policy_node.py --ros-args -p policy_dir:=/path/to/export

Subscribes to /scan (sensor_msgs/LaserScan), /odom (nav_msgs/Odometry) and /goal_pose
(geometry_msgs/PoseStamped, in the odometry frame); publishes /cmd_vel (geometry_msgs/Twist, or
TwistStamped with use_stamped:=true) every control period (the run's dt, meta.json), and a zero
command once the robot is within the goal radius (then it waits for the next goal), and a zero
command for an observation holding a NaN or an infinity (policy.py's `last_unsafe`).

All conversions (scan pooling, the observation, the actor, action -> velocities) are the exported
folder's policy.py; this file only moves messages. NOT TESTED: no ROS on the machines this was
written on (see README.md); policy.py's functions are tested in the project (tests/test_export.py).
Needs rclpy and numpy only (no JAX).
"""

from __future__ import annotations

import importlib.util
import os
import sys

import rclpy
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan


def load_policy_module(folder: str):
    """Import the exported folder's policy.py (numpy + standard library only)."""
    path = os.path.join(folder, "policy.py")
    if not os.path.exists(path) or not os.path.exists(os.path.join(folder, "weights.npz")):
        raise FileNotFoundError(
            f"{folder}: not a numpy export (needs policy.py and weights.npz; "
            "fedjax-nav export RUN_DIR --format numpy --out DIR)"
        )
    spec = importlib.util.spec_from_file_location("fedjax_nav_exported_policy", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class PolicyNode(Node):
    def __init__(self):
        super().__init__("fedjax_nav_policy")
        p = self.declare_parameter
        folder = p("policy_dir", os.environ.get("FEDJAX_NAV_POLICY", "")).value
        if not folder:
            raise SystemExit("set the exported folder: --ros-args -p policy_dir:=/path/to/export")
        self.mod = load_policy_module(folder)
        self.policy = self.mod.Policy(folder)
        meta = self.policy.meta
        self.period = float(p("control_period", float(meta.get("dt", 0.1))).value)
        self.goal_radius = float(p("goal_radius", float(meta.get("goal_radius", 0.5))).value)
        # Safety limits of the robot (TurtleBot3 Burger: 0.22 m/s, 2.84 rad/s); the policy's own
        # limits are the run's v_max / omega_max (meta.json). The smaller one wins.
        self.max_linear = float(p("max_linear", 0.22).value)
        self.max_angular = float(p("max_angular", 2.84).value)
        self.pooling = str(p("pooling", "min").value)  # "min" (sector minimum) or "nearest"
        invalid = float(p("invalid_range", -1.0).value)  # < 0: drop NaN/0/below-range_min samples
        self.invalid = None if invalid < 0 else invalid
        self.angle_offset = float(p("laser_yaw", 0.0).value)  # the laser's yaw in base_link, rad
        self.timeout = float(p("sensor_timeout", 0.5).value)  # s without scan/odom -> stop
        self.stamped = stamped = bool(p("use_stamped", False).value)

        self.scan = None
        self.scan_time = None
        self.pose = None
        self.odom_frame = None
        self.odom_time = None
        self.goal = None
        self.prev_action = (0.0, 0.0)  # network units, as the simulator's observation holds it

        self.create_subscription(LaserScan, p("scan_topic", "/scan").value, self.on_scan, qos_profile_sensor_data)
        self.create_subscription(Odometry, p("odom_topic", "/odom").value, self.on_odom, 10)
        self.create_subscription(PoseStamped, p("goal_topic", "/goal_pose").value, self.on_goal, 10)
        self.pub = self.create_publisher(TwistStamped if stamped else Twist, p("cmd_vel_topic", "/cmd_vel").value, 10)
        self.timer = self.create_timer(self.period, self.on_timer)
        self.get_logger().info(
            f"policy {folder}: {meta.get('method')} seed {meta.get('seed')} agent {meta.get('agent')}, "
            f"{self.policy.num_beams} beams, max_range {self.policy.max_range} m, v_max {self.policy.v_max} m/s, "
            f"omega_max {self.policy.omega_max} rad/s, every {self.period} s, goal radius {self.goal_radius} m"
        )

    # ------------------------------------------------------------------ inputs

    def now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_scan(self, msg: LaserScan):
        self.scan = msg
        self.scan_time = self.now()

    def on_odom(self, msg: Odometry):
        q = msg.pose.pose.orientation
        yaw = self.mod.yaw_from_quaternion(q.x, q.y, q.z, q.w)
        self.pose = (msg.pose.pose.position.x, msg.pose.pose.position.y, yaw)
        self.odom_frame = msg.header.frame_id
        self.odom_time = self.now()

    def on_goal(self, msg: PoseStamped):
        if self.odom_frame and msg.header.frame_id and msg.header.frame_id != self.odom_frame:
            self.get_logger().warn(
                f"goal in frame '{msg.header.frame_id}', odometry in '{self.odom_frame}': no tf lookup is "
                "done, the goal is taken as odometry coordinates (set RViz's fixed frame to the odom frame)"
            )
        self.goal = (msg.pose.position.x, msg.pose.position.y)
        self.prev_action = (0.0, 0.0)  # a new episode
        self.policy.reset()  # a recurrent policy's hidden state starts from zeros (a no-op otherwise)
        self.get_logger().info(f"goal ({self.goal[0]:.2f}, {self.goal[1]:.2f})")

    # ------------------------------------------------------------------ control

    def publish(self, v: float, omega: float):
        msg = Twist()
        msg.linear.x, msg.angular.z = float(v), float(omega)
        if self.stamped:
            out = TwistStamped()
            out.header.stamp = self.get_clock().now().to_msg()
            out.header.frame_id = "base_link"
            out.twist = msg
            msg = out
        self.pub.publish(msg)

    def on_timer(self):
        if self.goal is None:
            return
        t = self.now()
        if (
            self.scan is None
            or self.pose is None
            or t - self.scan_time > self.timeout
            or t - self.odom_time > self.timeout
        ):
            self.get_logger().warn("no recent /scan or /odom: stopping", throttle_duration_sec=2.0)
            self.publish(0.0, 0.0)
            return
        dist = float(self.mod.goal_features(self.pose, self.goal)[0])
        if dist < self.goal_radius:  # where a simulated episode ends
            self.publish(0.0, 0.0)
            self.get_logger().info(f"goal reached (within {self.goal_radius} m)")
            self.goal = None
            return
        s = self.scan
        ranges = self.policy.scan_ranges(
            s.ranges,
            s.angle_min,
            s.angle_increment,
            s.range_min,
            s.range_max,
            angle_offset=self.angle_offset,
            invalid=self.invalid,
            mode=self.pooling,
        )
        obs = self.policy.observation(ranges, self.pose, self.goal, self.prev_action)
        action = self.policy(obs)  # NaN/inf anywhere in obs: the stop command, flagged (policy.py)
        if self.policy.last_unsafe:
            self.get_logger().warn(
                "non-finite observation (NaN/inf from the odometry or the goal): stopping", throttle_duration_sec=2.0
            )
            self.publish(0.0, 0.0)
            self.prev_action = (0.0, 0.0)
            return
        v, omega = self.policy.velocity(action)
        v = min(v, self.max_linear)
        omega = max(-self.max_angular, min(omega, self.max_angular))
        self.publish(v, omega)
        self.prev_action = (float(action[0]), float(action[1]))


def main(argv=None):
    rclpy.init(args=argv if argv is not None else sys.argv)
    node = PolicyNode()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.publish(0.0, 0.0)  # leave the robot stopped
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()
