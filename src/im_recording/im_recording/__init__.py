"""
Recording of a drive run.

MCAP writer/reader, lossless recorder, replay, recover, run analysis, report.
"""
