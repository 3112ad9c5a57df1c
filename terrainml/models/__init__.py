"""Terrain classifiers on raw windows (SYSTEM §9).

:mod:`.svm` (features + RBF SVM), :mod:`.cnn` (1-D CNN), :mod:`.cv` (grouped CV),
:mod:`.metrics`, :mod:`.artifacts` (verified model folders), :mod:`.report`, :mod:`.dataset`
(window datasets from logs), :mod:`.train` (train / evaluate).
"""
