"""The built-in robot specs, one ``NAME.yaml`` each in this package, by name.

Only the names live here (no numpy, no yaml), so that the command line's help lists them without
importing :mod:`terrainml.robot`, which reads the specs.
"""

#: the robot specs shipped with the package
BUILTIN_ROBOTS = ("agrimaro", "husky", "skidsteer_tracked")
#: the reference robot (design §3): what a command or function given no robot uses
REFERENCE_ROBOT = "agrimaro"
