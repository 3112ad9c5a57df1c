"""Online serving (design §11): the predictor, its message, sources and sinks.

``Predictor.step(sample) -> DesiredSlip`` runs the offline estimation, window and feature code
tick by tick; ``terrainml predict`` connects it to a source and sinks.
"""

from terrainml.stream.message import DesiredSlip, json_schema

__all__ = ["DesiredSlip", "json_schema"]
