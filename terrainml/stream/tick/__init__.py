"""One serving tick: a sample in, a desired-slip message out.

:class:`~terrainml.stream.tick.predictor.Predictor` owns the tick and calls, in order: the clock
gate (:mod:`.clock`), the sample check (:mod:`.sample`), the online estimator (:mod:`.estimate`),
the ring of estimator rows (:mod:`.ring`), the classification scheduler (:mod:`.scheduler`) and
its window classifier (:mod:`.classify`), the member vote (:mod:`.member_vote`), the terrain
filter (:mod:`.fusion`), the serving policy (:mod:`.policy`), sensor health (:mod:`.health`),
the odometer (:mod:`.odometer`), and builds the message (:mod:`.message`). It imports neither
transports nor the application.
"""
