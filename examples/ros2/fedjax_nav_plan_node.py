#!/usr/bin/env python3
"""The ROS 2 node for a policy trained with the global plan (`env.plan: true`, docs/planning.md).

    python3 fedjax_nav_plan_node.py --ros-args -p policy_dir:=/path/to/export

Everything of fedjax_nav_policy_node.py (its topics, parameters, stops; that file, beside this
one, is imported as it is), and the robot's own planner's path: it subscribes to `plan_topic`
(default /plan, nav_msgs/Path: what nav2's planner server publishes) and gives the policy, as its
waypoint, the first pose of the path at least the run's `plan_lookahead` m along it from the robot,
else the path's last pose (policy.py's `path_waypoint`, mirroring the simulator's walk down its
field; docs/export.md, "Exporting a plan run"). Without a path to the current goal (none received
yet, or the last one ends farther than the goal radius from the goal: a path to another goal) it
publishes a zero command and logs it once.

Like the goal, the path is taken in the odometry frame: no tf lookup is done (a warning, once, for
a path in another frame). NOT TESTED with ROS (see README.md); tests/test_export_plan.py runs it
against stand-ins for rclpy and the message classes. Needs rclpy and numpy only (no JAX).
"""

from __future__ import annotations

import sys

import numpy as np
import rclpy
from nav_msgs.msg import Path

try:  # in a ROS 2 package beside the mapless node
    from .fedjax_nav_policy_node import PolicyNode
except ImportError:  # run as a script from this folder
    from fedjax_nav_policy_node import PolicyNode


class PlanNode(PolicyNode):
    def __init__(self):
        super().__init__()
        if self.policy.lookahead is None:
            raise SystemExit(
                f"{self.policy.folder}: a mapless export (no plan in meta.json): run fedjax_nav_policy_node.py"
            )
        self.path = None  # float[n, 2] in the path's frame, from the last Path message
        self.path_frame_warned = False
        self.waiting = False  # a zero command for want of a path is logged once per wait
        topic = self.declare_parameter("plan_topic", "/plan").value
        self.create_subscription(Path, topic, self.on_plan, 10)
        self.get_logger().info(f"waypoint {self.policy.lookahead} m down the path on {topic}")

    def on_plan(self, msg: Path):
        frame = msg.header.frame_id
        if self.odom_frame and frame and frame != self.odom_frame and not self.path_frame_warned:
            self.get_logger().warn(
                f"path in frame '{frame}', odometry in '{self.odom_frame}': no tf lookup is done, the path "
                "is taken as odometry coordinates"
            )
            self.path_frame_warned = True
        self.path = np.array([(p.pose.position.x, p.pose.position.y) for p in msg.poses], np.float64).reshape(-1, 2)

    def path_to_goal(self):
        """The last path when it ends within the goal radius of the current goal, else None."""
        if self.path is None or self.goal is None or len(self.path) == 0:
            return None
        end = self.path[-1]
        return self.path if np.hypot(end[0] - self.goal[0], end[1] - self.goal[1]) <= self.goal_radius else None

    def on_timer(self):
        path = self.path_to_goal()
        self.policy.follow(path)
        if self.goal is not None and path is None:
            if not self.waiting:
                self.get_logger().info("no path to the goal yet on the plan topic: zero command until one comes")
                self.waiting = True
            self.publish(0.0, 0.0)
            return
        self.waiting = False
        super().on_timer()


def main(argv=None):
    rclpy.init(args=argv if argv is not None else sys.argv)
    node = PlanNode()
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
