"""The built-in dataset specs' names (``terrainml/io/datasets/NAME.yaml``; ``--format NAME``).

Apart from :mod:`terrainml.io.ingest.dataset_spec` (which reads the specs with pandas) so that the
command line's help lists them without importing the readers.
"""

#: the dataset specs shipped with the package, by name
BUILTIN_SPECS = ("borealtc",)
