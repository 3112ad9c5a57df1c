"""Where serving samples come from and where its messages go.

* :mod:`.sources` -- ``--source``: a recorded run, UDP datagrams, or ROS 2 (:mod:`.ros2`);
* :mod:`.sinks` -- ``--sink``: stdout, MCAP, CAN, UDP, and the guard that isolates a failing sink;
* :mod:`.foxglove_sink` -- ``--sink foxglove://``: a live Foxglove WebSocket server;
* :mod:`.ros2` -- ROS 2 over DDS, as a source and as a sink.
"""
