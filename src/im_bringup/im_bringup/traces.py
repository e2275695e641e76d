"""Live capture of a graph run: the serialized messages every node publishes, turned into the
same :class:`im_bringup.run.Run` a recording gives — so the scenario's summary and the report of
its MCAP are computed by the same code (:func:`im_bringup.report.figures_of_merit`).

Capturing costs one list append per message (the payload bytes the node already built); the
decoding happens once, vectorized, at the end.
"""
from __future__ import annotations

from typing import Dict, List, Optional

from im_common.cdr import encode, header_stamp_ns


class Tap:
    """Graph publisher tap: keeps each published payload and, if given, writes it to a bag."""

    def __init__(self, writer=None, keep: bool = True):
        self.writer = writer
        self.keep = keep
        self.raw: Dict[str, List[bytes]] = {}

    def write(self, topic: str, data, ns: Optional[int] = None) -> None:
        if not isinstance(data, (bytes, bytearray)):
            data = encode(data)
        if ns is None:
            ns = header_stamp_ns(data)
        if self.keep:
            lst = self.raw.get(topic)
            if lst is None:
                lst = self.raw[topic] = []
            lst.append(data)
        if self.writer is not None:
            self.writer.write_serialized(topic, data, ns)

    def run(self, metadata: Optional[dict] = None, path: str = '<live>'):
        """The captured messages as a :class:`im_bringup.run.Run`."""
        from im_bringup.run import Run, build_trace, truth_final_from
        trace, series = build_trace(self.raw)
        return Run(path, trace, truth_final_from(series), metadata or {},
                   {t: len(v) for t, v in self.raw.items()})
