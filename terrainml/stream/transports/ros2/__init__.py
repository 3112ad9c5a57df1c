"""``terrainml predict`` as a ROS 2 participant over DDS (docs/ros2.md).

* :mod:`.names` -- ROS 2 names on DDS (``/foo`` -> ``rt/foo``, ``pkg/msg/T`` -> ``pkg::msg::dds_::T_``),
  the ``ros2://DOMAIN`` URL, QoS profiles;
* :mod:`.types` -- the ROS messages read and published, as Cyclone DDS IDL structs (XCDR1);
* :mod:`.align` -- live messages -> base-rate samples by the ingest engine's rules;
* :mod:`.source` -- ``--source ros2://DOMAIN``: the topic map's topics, aligned into samples;
* :mod:`.sink` -- ``--sink ros2://DOMAIN``: desired slip, terrain class, diagnostics, slip-aware odometry.
"""
