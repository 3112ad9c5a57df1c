"""terrainml: terrain-aware traction for wheeled field robots.

Data flows one way: io -> estimation -> features -> models -> lookup -> stream -> control.
``sim`` writes logs through ``io``; nothing in the chain imports ``sim``.
"""

__version__ = "0.1.0"
