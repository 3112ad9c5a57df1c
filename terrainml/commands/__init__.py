"""CLI command groups, one module per area; each exposes ``register(app)``.

Keeping each area's commands in its own module lets ``cli.py`` stay a short table of contents.
"""

AREAS = ("io_cmds", "sim_cmds", "estimation_cmds", "lookup_cmds", "dataset_cmds", "model_cmds",
         "stream_cmds", "control_cmds", "mission_cmds", "slipmap_cmds", "borealtc_cmds")
