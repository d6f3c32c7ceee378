"""Reading a dataset: where its files are (`paths`), what its columns are called and hold (`schema`), and its two
readers, the sidecar's (`sidecar`: run.json and the attempt tables) and LeRobot's (`lerobot`: the episodes).

The run loop, `verify`, `report`, `view` and the world-model evaluation read through this package; the writers
(`babblegen.exporters`, the run store) take its paths and schema from it. It imports no writer and nothing above
the world's light modules; LeRobot itself loads only when a dataset is opened.
"""
