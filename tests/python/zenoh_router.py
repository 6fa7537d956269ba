"""A Zenoh router on one loopback endpoint, multicast scouting off (PyPI `eclipse-zenoh` only): the
meeting point of the ROS 2 tests, standing in for `rmw_zenohd` or `zenoh-bridge-ros2dds`.

Usage: zenoh_router.py PORT   (runs until killed; prints "ready" once listening)
"""

import sys
import time

import zenoh

config = zenoh.Config()
config.insert_json5("mode", '"router"')
config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)
print("ready", flush=True)
while True:
    time.sleep(3600)
