"""
Bringing the drive up.

The launch file, configuration, the scenario runner, the graph and process starters.
"""
