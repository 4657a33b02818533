# rosbridge v2 server: protocol codec, ROS 2 message types, rosapi, topics and the WS component.
from __future__ import annotations
