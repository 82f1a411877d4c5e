"""Exporters: demo files → other tools' formats (LeRobotDataset v3.0, per-step Foxglove MCAP)."""
