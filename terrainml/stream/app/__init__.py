"""The ``terrainml predict`` application: a source, the predictor and the sinks joined in one loop.

* :mod:`.runner` -- the serving loop, its shutdown and its summary;
* :mod:`.recorder` -- ``--record-unknown``: stretches of unknown ground written as runs to label.
"""
