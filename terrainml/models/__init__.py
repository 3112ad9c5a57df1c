"""Terrain classifiers on windows (design §9): estimators only.

:mod:`.svm` (features + RBF SVM), :mod:`.cnn` (1-D CNN), :mod:`.artifacts` (verified model
folders), :mod:`.onnx_export`. Cross-validation and reports live in :mod:`terrainml.evaluation`,
dataset build and training in :mod:`terrainml.pipeline`.
"""
