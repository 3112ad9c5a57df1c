"""Online serving, ``terrainml predict``, in three rooms.

* :mod:`terrainml.stream.tick` -- one tick: a sample in, a :class:`~terrainml.stream.tick.message.DesiredSlip` out
  (clock gate, estimator, ring, classifier, fusion, policy, health);
* :mod:`terrainml.stream.transports` -- where samples come from and messages go (log, UDP, ROS 2,
  MCAP, CAN, Foxglove);
* :mod:`terrainml.stream.app` -- the application joining them (runner, recorder, replay scores).
"""
