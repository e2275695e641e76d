"""Bringing the drive up: the launch file, configuration, the scenario runner, the graph and process starters."""
