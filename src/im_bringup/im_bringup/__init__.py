"""Whole-system tools: scenario runner, recorder, replay, report, launch file."""
