"""Replay: the robot runtime over recorded sequences (frame folders, videos): commands.csv, an overlay video and a plot."""
