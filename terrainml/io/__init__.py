"""Log ingest and export: ROS 2 MCAP, ROS 1 bag, CSV and Parquet into the canonical run table."""
