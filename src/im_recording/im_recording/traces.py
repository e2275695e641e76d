"""
Live capture of a graph run.

The serialized messages every node publishes, summarized while the run goes into the same
:class:`im_recording.recorded_run.RecordedRun` a recording gives — so the scenario's summary and
the report of its MCAP are computed by the same code
(:class:`im_recording.recorded_run.RunningFigures` behind
:func:`im_recording.report.figures_of_merit`).

Memory stays bounded: the payloads are decoded and folded into running sums every
:attr:`im_recording.recorded_run.TraceStream.batch` messages and then dropped; the per-step
trace is kept only when asked (``keep=True``: every row, for tests; ``keep='decimated'``: a few
thousand rows).
"""
from __future__ import annotations

from typing import Optional, Union

from im_common.cdr import encode, header_stamp_ns
from im_common.topics import RECORDED_TOPICS
from im_recording.bag import BagError
from im_recording.recorded_run import (lockstep_topics, RecordedRun, RunningFigures, TraceKeeper,
                                       TraceStream, TruthBooks)
from im_recording.session import RecordingSession

#: the ``recorder`` record's ``node`` of a recording made in-process (im_bringup.graph)
IN_PROCESS = 'in-process graph (im_bringup.graph.DriveGraph)'


class Tap:
    """
    Graph publisher tap.

    Folds each published payload into the run's figures and, if given, writes it to a bag.

    ``keep``: True keeps the whole per-step trace (memory grows with the run), 'decimated'
    about ``limit`` rows, False none (the figures still cover every step). ``held``: the
    estimates a run without an adapter holds (its controller's model, RunningFigures.held).
    """

    def __init__(self, writer=None, keep: Union[bool, str] = True, limit: int = 10000,
                 load_step: Optional[float] = None, held: Optional[dict] = None):
        self.writer = writer
        #: the recording's bookkeeping and metadata records, as the recorder node's (the graph
        #: feeds it the run's period, events and parameters; :meth:`close` ends it)
        self.session = None if writer is None else RecordingSession(
            writer, RECORDED_TOPICS, recorder=IN_PROCESS)
        self.error: Optional[str] = None    # why the writer stopped (its file cannot be written)
        self.on_error = None                # called with that line (a graph ends its run)
        self.keep = keep
        self.books = TruthBooks()
        self.figures = RunningFigures(lockstep_topics=lockstep_topics(), load_step=load_step,
                                      held=held)
        sinks = [self.books, self.figures]
        self.keeper = None
        if keep:
            self.keeper = TraceKeeper(None if keep is True else limit)
            sinks.append(self.keeper)
        self.stream = TraceStream(sinks)
        self._run = None

    def write(self, topic: str, data, ns: Optional[int] = None) -> None:
        if not isinstance(data, (bytes, bytearray)):
            data = encode(data)
        if self.writer is not None:
            if ns is None:
                ns = header_stamp_ns(data)
            try:
                self.session.write(topic, data, ns)
            except BagError as exc:         # the recording's file cannot be written (disk full)
                self._failed(exc)
        self.stream.add(topic, data)

    def close(self, interrupted: Optional[str] = None) -> None:
        """
        End the recording: its ``recording`` record, then the file (nothing without a writer).

        ``interrupted``: the stop signal's name, if one ended the run.
        """
        if self.session is not None:
            self.session.close(interrupted)

    def flush_due(self) -> None:
        """Put the writer's open chunk on disk if it is due (:meth:`BagWriter.flush_due`)."""
        if self.writer is None:
            return
        try:
            self.writer.flush_due()
        except BagError as exc:
            self._failed(exc)

    def _failed(self, exc) -> None:
        if not self.writer.failed:
            raise exc
        self.writer = None          # what it wrote stays in its .part (recover)
        self.error = str(exc)
        if self.on_error is not None:
            self.on_error(self.error)

    def run(self, metadata: Optional[dict] = None, path: str = '<live>'):
        """Return the capture as a :class:`~im_recording.recorded_run.RecordedRun` (ends it)."""
        if self._run is None:
            self.stream.flush(final=True)
            tr = self.keeper.trace() if self.keeper is not None else {}
            self._run = RecordedRun(path, tr, self.books.final(), metadata or {},
                                    dict(self.stream.counts), running=self.figures,
                                    late=self.stream.late)
        return self._run
