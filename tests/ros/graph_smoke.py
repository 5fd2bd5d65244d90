"""Driver (run by tests/ros/test_graph.py inside a private network namespace): the interfaces this process sees,
and one message published and received over Fast DDS between two processes."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time

if sys.argv[1:] == ["listen"]:
    import rclpy
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node("listener")
    got: list[str] = []
    node.create_subscription(String, "chatter", lambda m: got.append(m.data), 10)
    end = time.monotonic() + 30
    while not got and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps({"kind": "heard", "data": got[:1]}), flush=True)
    sys.exit(0 if got else 1)

print(json.dumps({"kind": "interfaces", "names": sorted(n for _, n in socket.if_nameindex())}), flush=True)
print(
    json.dumps(
        {
            "kind": "env",
            "range": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE"),
            "domain": os.environ.get("ROS_DOMAIN_ID"),
        }
    ),
    flush=True,
)
listener = subprocess.Popen([sys.executable, __file__, "listen"], stdout=subprocess.PIPE, text=True)
import rclpy  # noqa: E402
from std_msgs.msg import String  # noqa: E402

rclpy.init()
node = rclpy.create_node("talker")
pub = node.create_publisher(String, "chatter", 10)
end = time.monotonic() + 30
while listener.poll() is None and time.monotonic() < end:
    pub.publish(String(data="over loopback"))
    rclpy.spin_once(node, timeout_sec=0.1)
out, _ = listener.communicate(timeout=10)
print(out.strip(), flush=True)
