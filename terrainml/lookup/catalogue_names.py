"""The built-in terrain catalogues' names (``terrainml/lookup/catalogues/NAME.yaml``).

Apart from :mod:`terrainml.lookup.catalogue` (which parses them) so that the command line's help
lists them without importing the lookup.
"""

#: the terrain catalogues shipped with the package: ``reference`` is the eight simulated classes
BUILTIN_CATALOGUES = ("reference", "borealtc")
