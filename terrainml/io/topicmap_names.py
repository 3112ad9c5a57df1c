"""The built-in topic maps' names (``terrainml/io/topicmaps/NAME.yaml``, design §5).

Apart from :mod:`terrainml.io.topicmap` (which reads the maps through the CDR decoders) so that the
command line's help lists them without importing the readers.
"""

#: the topic maps shipped with the package, by name; ``default`` is the design §5 map
BUILTIN_MAPS = ("default", "husky_robot_localization", "husky_ros2")
