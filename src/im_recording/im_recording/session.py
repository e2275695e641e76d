"""
One recording of a run: the bag, what it holds, and the metadata it closes with.

A :class:`RecordingSession` is the one home of a recording's bookkeeping, whichever path feeds
it: the recorder node across processes (:class:`im_recording.record_node.RecorderNode`, from
its subscriptions) and the in-process graph (:class:`im_bringup.graph.DriveGraph`, from its
nodes' tap). It owns the :class:`~im_recording.bag.BagWriter` and

* counts the messages written per topic and checks each lock-step topic's stamps step by step
  (:class:`StampTrack`);
* follows the time master's events (the run's period, its first step, its end state);
* writes the same metadata records with the same keys on both paths: ``recorder`` (who records
  what) when it starts, ``parameters/<node>`` for each node of the run (every parameter with its
  value, defaults included; a node that is not part of the run — the adapter when it is off —
  has none), and ``recording`` when it closes (messages, the run's end, the signal that
  interrupted it, the steps missing per lock-step topic and over which steps they were counted,
  the parameters asked for and not received).

ROS-free: the nodes hand it serialized messages, stamps and event values.
"""
from __future__ import annotations

import time
from typing import Callable, Dict, Iterable, List, Mapping, Optional

from im_common import topics as T
from im_common.lockstep_protocol import ENDED, FINISHED, LosslessFollower

from .bag import BagError, parameters_metadata

#: The name of the Metadata record that says who recorded the file.
RECORDER_RECORD = 'recorder'
#: The name of the Metadata record that sums up the recording when it closes.
RECORDING_RECORD = 'recording'


class StampTrack:
    """
    Per-topic continuity check of a lock-step topic.

    It keeps the first and last stamp received and the steps missing between received stamps
    (cheap enough for every message); the steps missing before the first and after the last are
    added by :meth:`account`, once the run's first and last step are known.
    """

    __slots__ = ('first', 'last', 'missing', 'ranges', 'overflow')

    MAX_RANGES = 100

    def __init__(self):
        self.first: Optional[int] = None
        self.last: Optional[int] = None
        self.missing = 0
        self.ranges: List[tuple] = []
        self.overflow = False

    def see(self, ns: int, period: int) -> None:
        last = self.last
        if last is None:
            self.first = self.last = ns
            return
        if ns > last:
            if period and ns > last + period:
                self.missing += (ns - last) // period - 1
                if len(self.ranges) < self.MAX_RANGES:
                    self.ranges.append((last + period, ns - period))
                else:
                    self.overflow = True
            self.last = ns
        elif ns < self.first:           # an earlier step after a later one: before the first
            if period and self.first - ns > period:
                self.missing += (self.first - ns) // period - 1
                if len(self.ranges) < self.MAX_RANGES:
                    self.ranges.insert(0, (ns + period, self.first - period))
                else:
                    self.overflow = True
            self.first = ns
        elif period and ns < last:      # late into a gap counted missing: no longer missing
            self._fill(ns, period)

    def _fill(self, ns: int, period: int) -> None:
        for i, (a, b) in enumerate(self.ranges):
            if a <= ns <= b:
                self.missing -= 1
                parts = [(a, ns - period)] if ns > a else []
                parts += [(ns + period, b)] if ns < b else []
                self.ranges[i:i + 1] = parts
                return
        # not in a listed gap: a duplicate, or a gap beyond the MAX_RANGES listed (overflow: the
        # count may then stay too high; the metadata says missing_ranges_truncated<topic>)

    def account(self, start: Optional[int], end: Optional[int], period: int) -> tuple:
        """
        Return (steps missing, their ranges) from ``start`` to ``end``.

        ``start`` and ``end`` are stamps, both included (None: not known, nothing counted on that
        side). The steps are those before the first stamp received, between received stamps, and
        after the last, within ``start``-``end`` only: a gap between stamps received outside it
        (a late recorder's observer flux that first came after it was stopped) is not the span's.
        """
        if self.first is None:
            if start is None or end is None or not period or end < start:
                return 0, []
            return (end - start) // period + 1, [(start, end)]
        n, ranges = self.missing, list(self.ranges)
        if start is not None and period and self.first > start:
            n += (self.first - start) // period
            ranges.insert(0, (start, self.first - period))
        if end is not None and period and self.last < end:
            n += (end - self.last) // period
            ranges.append((self.last + period, end))
        if not period or (start is None and end is None):
            return n, ranges
        lo = start if start is not None else ranges[0][0] if ranges else 0
        hi = end if end is not None else ranges[-1][1] if ranges else 0
        inside = []
        for a, b in ranges:
            a2, b2 = max(a, lo), min(b, hi)
            n -= (b - a) // period + 1 - ((b2 - a2) // period + 1 if b2 >= a2 else 0)
            if b2 >= a2:
                inside.append((a2, b2))
        return n, inside


class RecordingSession:
    """
    The bookkeeping of one recording (module docstring).

    Parameters
    ----------
    writer : BagWriter
        The file; the session writes its ``recorder`` record at once.
    topics : iterable of str
        The topics recorded; the lock-step topics among them are tracked step by step.
    recorder : str
        Who records (the ``recorder`` record's ``node``).
    always : iterable of str
        Lock-step topics every run has (counted even when nothing came on them).
    announced : callable returning the lock-step topics the run's nodes announced
        (also counted when nothing came).
    run : the run's start and end as followed
        (:class:`~im_common.lockstep_protocol.LosslessFollower`, the one home of them: a recorder
        node passes its own; default a new one fed by :meth:`master_event`).

    """

    def __init__(self, writer, topics: Iterable[str], recorder: str,
                 always: Iterable[str] = (), announced: Callable[[], Iterable[str]] = tuple,
                 run: Optional[LosslessFollower] = None):
        self.writer = writer
        self.topics = list(topics)
        self.counts: Dict[str, int] = dict.fromkeys(self.topics, 0)
        lockstep = set(T.LOCKSTEP_TOPICS)
        self.track: Dict[str, StampTrack] = {t: StampTrack() for t in self.topics
                                             if t in lockstep}
        self.always = tuple(always)
        self.announced = announced
        self.period = 0                          # of the run [ns], from the time master
        self.run = run if run is not None else LosslessFollower(self.always, list(self.track))
        self.stop_at: Optional[int] = None       # see cut()
        self.undecodable = 0
        self.unsigned: Dict[str, int] = {}       # topic -> messages not signed by the graph
        self.foreign: Dict[str, set] = {}        # topic -> their publishers, as named
        self.parameters_asked: List[str] = []    # nodes of the run whose parameters are due
        self.parameters_written: List[str] = []
        self.last_wall = 0.0                     # monotonic time of the last message written
        self._write = writer.write_serialized
        self._track = self.track.get
        writer.add_metadata(RECORDER_RECORD, {
            'node': recorder, 'topics': ' '.join(self.topics),
            'started_wall': time.strftime('%Y-%m-%dT%H:%M:%S%z')})

    # The run as followed (its one home: self.run) ---------------------------------------------
    run_start = property(lambda self: self.run.run_start,
                         doc="Stamp of the run's first step (None: not running yet).")
    from_start = property(lambda self: self.run.from_start,
                          doc='Whether the time master counted this recording from step 0.')
    end_state = property(lambda self: self.run.end_state,
                         doc="The time master's final event (ENDED: it left without one).")
    end_values = property(lambda self: self.run.end_values, doc='Its values.')

    # Messages ---------------------------------------------------------------------------
    def write(self, topic: str, data: bytes, ns: int) -> None:
        """
        Write one serialized message stamped ``ns``, count it and check its step.

        The writer's :class:`~im_recording.bag.BagError` (closed, or its file cannot be
        written: ``writer.failed``) goes to the caller; the message is then not counted.
        """
        self._write(topic, data, ns)
        counts = self.counts
        counts[topic] = counts.get(topic, 0) + 1
        tr = self._track(topic)
        if tr is not None:
            tr.see(ns, self.period)

    def refused(self, topic: str, publishers: Iterable[str] = ()) -> int:
        """Count a message not signed by the graph on ``topic``; returns the count so far."""
        n = self.unsigned[topic] = self.unsigned.get(topic, 0) + 1
        self.foreign.setdefault(topic, set()).update(publishers)
        return n

    # The run ----------------------------------------------------------------------------
    def master_event(self, state: str, values: Mapping[str, str],
                     counted: bool = True, node: str = 'plant') -> None:
        """
        Take an event of the run's time master (its ``/im/status`` values, strings).

        Its period; the run's first step when it starts running (``counted``: the plant counts
        this recording from that step, as its ``followers`` say for a recorder node); its final
        event.
        """
        period = int(values.get('T_s_ns', 0) or 0)
        if period:
            self.period = period
        self.run.master_event(node, state, values, self.period, '', time.monotonic(),
                              counted=counted)

    def run_topics(self) -> List[str]:
        """
        Return the lock-step topics of the run this recording counts.

        Those every graph has (``always``), those a node of the run announced, and any that
        brought data of the run.
        """
        announced = set(self.announced())
        return [t for t, tr in self.track.items()
                if t in self.always or t in announced or tr.first is not None]

    def count_span(self) -> tuple:
        """
        Return (first step, last step, how the last is known) the missing steps are counted over.

        First: the run's first step when the plant counted this recording from the start (its
        ``running`` lists it), else — it joined a running run — the step it joined: the earliest
        step it holds on any lock-step topic of the run. Last: the step of the plant's final event;
        without one (the recorder was stopped, or the plant left, while the run went on) the last
        step the run announced to it, the latest stamp it received on any lock-step topic.
        Steps are None where nothing is known.
        """
        p = self.period
        if not p:
            return None, None, ''
        if self.from_start and self.run_start is not None:
            first = self.run_start // p
        else:
            firsts = [self.track[t].first for t in self.run_topics()
                      if self.track[t].first is not None]
            first = min(firsts) // p if firsts else None
        if self.end_state is not None and self.end_state != ENDED:
            return first, int(self.end_values.get('step', 0) or 0), \
                f"the plant's final event ({self.end_state})"
        if self.stop_at is not None:
            return first, self.stop_at, ('the last step the run had announced when this '
                                         'recorder was stopped; the run went on')
        lasts = [tr.last for tr in self.track.values() if tr.last is not None]
        if not lasts:
            return first, None, ''
        how = 'the last step the run announced to this recorder; its end was not seen'
        return first, max(lasts) // p, how

    def cut(self) -> None:
        """
        Stop counting at the last step the run has announced (the recorder stops, the run not).

        Messages of later steps that still arrive (while the recorder waits for the plant's
        final event, which counts instead when it comes) are recorded but not counted.
        """
        if self.end_state is None and self.stop_at is None and self.period:
            lasts = [tr.last for tr in self.track.values() if tr.last is not None]
            if lasts:
                self.stop_at = max(lasts) // self.period

    def joined_at(self) -> Optional[int]:
        """Return the step this recording joined the run at, if it was not there from its start."""
        first = self.count_span()[0]
        if first is None or (self.from_start and self.run_start is not None):
            return None
        if self.run_start is not None and first * self.period <= self.run_start:
            return None
        return first

    def run_bounds(self, topic: str) -> tuple:
        """
        (first, last) stamp this recording must hold on ``topic`` (None: not known).

        Over :meth:`count_span`. The command of the last step is never computed when the run
        finished; after a stop, a failure or without the plant's final event only the
        measurements of the last step are sure to exist (the commands and estimates up to the
        step before).
        """
        p = self.period
        first, last, _ = self.count_span()
        if first is None and last is None:
            return None, None
        start = None if first is None else first * p
        end = None
        if last is not None:
            measured = topic in (T.MEAS_CURRENT, T.MEAS_SHAFT)
            if self.end_state == FINISHED:
                end = (last - 1 if topic == T.CMD_VOLTAGE else last) * p
            else:
                end = (last if measured else last - 1) * p
        return start, end

    def gaps(self) -> Dict[str, dict]:
        """
        Return, per tracked lock-step topic, the steps of the run it lacks and their stamp ranges.

        The steps lacking are those before its first stamp, between, and after its last, over
        :meth:`run_bounds`; a lock-step topic of the run with nothing recorded lacks them all.
        """
        out = {}
        topics = set(self.run_topics())
        for t, tr in self.track.items():
            if t in topics:
                n, ranges = tr.account(*self.run_bounds(t), self.period)
            else:
                n, ranges = 0, []
            out[t] = {'missing_steps': n, 'ranges': ranges[:StampTrack.MAX_RANGES]}
        return out

    def span_text(self) -> str:
        """Say over which steps the missing steps were counted (for the last line)."""
        first, last, how = self.count_span()
        joined = self.joined_at()
        if first is None:
            return 'nothing of a run received'
        head = (f'joined at step {joined} (the steps before are not in this recording)'
                if joined is not None else f'from step {first}')
        return head + (f' to step {last} ({how})' if last is not None else '')

    # Parameters -------------------------------------------------------------------------
    def expect_parameters(self, node: str) -> bool:
        """
        Note that ``node``'s parameters are due (a node of the run); False if already noted.

        A node noted and never given (:meth:`add_parameters`) is named in the ``recording``
        record's ``parameters_not_received``.
        """
        if node in self.parameters_asked:
            return False
        self.parameters_asked.append(node)
        return True

    def add_parameters(self, node: str, values: Mapping[str, object]) -> None:
        """Write ``parameters/<node>``: every parameter with its value (name -> value)."""
        self.expect_parameters(node)
        try:
            self.writer.add_metadata(f'parameters/{node}', parameters_metadata(values))
        except BagError:
            return                  # closed meanwhile: 'parameters_not_received' names it
        self.parameters_written.append(node)

    # Closing ----------------------------------------------------------------------------
    def close_metadata(self, interrupted: Optional[str]) -> Dict[str, str]:
        """Return the ``recording`` record (``interrupted``: the stop signal's name, if any)."""
        gaps = self.gaps()
        missing = sum(g['missing_steps'] for g in gaps.values())
        meta = {'messages': str(sum(self.counts.values())),
                'period_ns': str(self.period),
                'run_end': (f"{self.end_state} ({self.end_values.get('reason', '')})"
                            if self.end_state else 'not seen'),
                'interrupted': interrupted or '',
                'missing_steps': str(missing),
                'missing_counted': self.span_text(),
                'undecodable': str(self.undecodable),
                'written_late': str(self.writer.late_messages),
                'refused_unsigned': str(sum(self.unsigned.values())),
                'foreign_publishers': ' '.join(sorted({f'{n}@{t}' for t, nodes in
                                                      self.foreign.items() for n in nodes})),
                'parameters_not_received': ' '.join(
                    sorted(set(self.parameters_asked) - set(self.parameters_written)))}
        first, last, _ = self.count_span()
        if first is not None:
            meta['counted_from_step'] = str(first)
        if last is not None:
            meta['counted_to_step'] = str(last)
        joined = self.joined_at()
        if joined is not None:
            meta['joined_at_step'] = str(joined)
        for t, n in self.unsigned.items():
            meta[f'refused_unsigned{t}'] = str(n)
        for t, g in gaps.items():
            meta[f'missing_steps{t}'] = str(g['missing_steps'])
            if g['ranges']:
                meta[f'missing_ranges{t}'] = ' '.join(f'{a}-{b}' for a, b in g['ranges'])
            if self.track[t].last is not None:
                meta[f'last_stamp{t}'] = str(self.track[t].last)
            if self.track[t].overflow:      # a late step in a gap past the list stays counted
                meta[f'missing_ranges_truncated{t}'] = 'true'
        return meta

    def close(self, interrupted: Optional[str] = None) -> None:
        """
        Write the ``recording`` record and close the file (idempotent).

        A writer that failed (its file cannot be written) raises its :class:`BagError` here
        only if it had not already: what it wrote stays in its ``.part``.
        """
        w = self.writer
        if not w.closed and not w.failed:
            w.add_metadata(RECORDING_RECORD, self.close_metadata(interrupted))
        w.close()
